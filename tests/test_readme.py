"""The README's first fenced block is the contract with a new user: exactly two command lines,
line 1 the main job, line 2 the tests (what ``.ci/run`` executes). The README stays a page for
users (at most 300 lines), its Python examples run as written, and its links resolve."""

import re
import subprocess
import unicodedata
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


def test_readme_is_short():
    """The README is for users; measurements and references live in docs/."""
    assert len((ROOT / "README.md").read_text().splitlines()) <= 300


def test_readme_python_blocks_run(tmp_path, monkeypatch):
    """Every python block of the README runs as written, each in a fresh namespace."""
    text = (ROOT / "README.md").read_text()
    blocks = re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)
    assert len(blocks) >= 2
    monkeypatch.chdir(tmp_path)
    for i, code in enumerate(blocks):
        try:
            exec(
                compile(code, f"README.md python block {i + 1}", "exec"), {"__name__": "__readme__"}
            )
        except Exception as e:  # the message names the block
            raise AssertionError(f"README python block {i + 1} failed: {e!r}\n{code}") from e


def _slug(heading: str) -> str:
    """A heading's anchor, as Python-Markdown's ``toc`` extension (MkDocs) makes it."""
    text = unicodedata.normalize("NFKD", heading.replace("`", "")).encode("ascii", "ignore")
    text = re.sub(r"[^\w\s-]", "", text.decode("ascii")).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


def test_readme_links_resolve():
    """Every relative link of the README names a file or folder of the repository, and every
    anchor into a docs page one of its headings."""
    text = (ROOT / "README.md").read_text()
    targets = re.findall(r"\]\(([^)\s]+)\)", text)
    assert targets
    for target in targets:
        if re.match(r"[a-z]+:", target):
            continue
        path, _, anchor = target.partition("#")
        assert (ROOT / path).exists(), f"README links to a missing {path}"
        if anchor:
            headings = re.findall(r"^#{1,6} (.*)$", (ROOT / path).read_text(), re.M)
            slugs = {_slug(h) for h in headings}
            assert anchor in slugs, f"README links to a missing heading: {target}"
