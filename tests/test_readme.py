"""The README's first fenced block is the contract with a new user: exactly two command lines,
line 1 the main job, line 2 the tests (what ``.ci/run`` executes)."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _first_block_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    block = re.search(r"^```[^\n]*\n(.*?)^```", text, re.S | re.M).group(1)
    return [ln for ln in block.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]


def test_first_block_has_main_job_and_test_lines():
    lines = _first_block_commands()
    assert len(lines) == 2, lines
    assert "python -m experiments.two_rooms" in lines[0]
    assert "pytest" in lines[1]


def test_ci_runs_readme_line_two():
    script = (ROOT / ".ci" / "run").read_text()
    extract = re.search(r"cmd=\$\((.*)\)\n", script).group(1)
    out = subprocess.run(["bash", "-c", extract], cwd=ROOT, capture_output=True, text=True)
    assert out.stdout.strip() == _first_block_commands()[1]
