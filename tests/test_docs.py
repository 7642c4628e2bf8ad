"""The documentation site builds, its examples run, and every command it shows exists.

* ``mkdocs build --strict`` succeeds (a broken link, a missing anchor, a page missing from
  the docs or an API docstring mkdocstrings cannot read fails it), and the configuration's
  validation turns each of those into an error;
* the Python examples of the environment, constraint and scenario pages run as written;
* every ``python -m MODULE`` shown in the README or ``docs/*.md`` runs with ``--help`` (all
  of them in one process, ``docs/gen_cli.py help``), and every flag shown after it is one of
  that command's flags: a renamed module or flag breaks this test, not a reader;
* every command of the project is in the command-line reference.
"""

from __future__ import annotations

import ast
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(DOCS))
import gen_cli  # noqa: E402  (docs/gen_cli.py, the site's command-line helper)

PAGES = sorted(DOCS.glob("*.md"))  # docs/results/**/*.md are run outputs, not pages
SITE_TOOLS = ("mkdocs", "material", "mkdocstrings", "mkdocstrings_handlers.python")


def _missing_site_tools() -> list[str]:
    return [m for m in SITE_TOOLS if importlib.util.find_spec(m.split(".")[0]) is None
            or importlib.util.find_spec(m) is None]  # fmt: skip


def _mkdocs(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}  # Material's notice, not our warning
    return subprocess.run([sys.executable, "-m", "mkdocs", *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


@pytest.fixture(scope="module")
def site_tools():
    missing = _missing_site_tools()
    if missing:
        pytest.skip(f"the documentation site needs {', '.join(missing)}: "
                    'pip install -e ".[dev]"')  # fmt: skip


def test_site_builds_strict(site_tools, tmp_path):
    """``mkdocs build --strict`` into a temporary directory: every warning is an error."""
    site = tmp_path / "site"
    out = _mkdocs(["build", "--strict", "-d", str(site)], ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    experiments = (site / "experiments" / "index.html").read_text()
    assert "--penalty-warmup" in experiments and "hazard_rooms" in experiments  # the hook ran
    assert "<!-- flags:" not in experiments
    cli = (site / "cli" / "index.html").read_text()
    assert "--batch-streams" in cli and "--num-envs" in cli  # checker.memory's, benchmarks'
    api = (site / "api" / "jaxgrid" / "index.html").read_text()
    assert "jaxgrid.registry.make" in api  # mkdocstrings rendered the docstrings
    if (ROOT / "jaxgrid" / "gymnax.py").exists():
        assert 'id="jaxgrid.gymnax"' in api


def test_strict_validation_fails_on_broken_links_and_missing_pages(site_tools, tmp_path):
    """The site's ``validation`` settings, in a tiny project with a page missing from the
    nav's files, a link to a missing page and a link to a missing anchor: the strict build
    fails and names all three."""
    import yaml

    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "index.md").write_text("# Home\n\n[gone](gone.md) and [no anchor](#nowhere)\n")
    tiny = {"site_name": "t", "validation": config["validation"],
            "nav": [{"Home": "index.md"}, {"Missing": "missing.md"}]}  # fmt: skip
    (tmp_path / "mkdocs.yml").write_text(yaml.safe_dump(tiny))
    out = _mkdocs(["build", "--strict", "-d", str(tmp_path / "site")], tmp_path)
    log = out.stdout + out.stderr
    assert out.returncode != 0, log
    assert "missing.md" in log and "gone.md" in log and "nowhere" in log, log


def _python_blocks(text: str) -> list[str]:
    return re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)


# The pages whose examples are self-contained (the others need a trained checker or a run).
RUNNABLE_PAGES = ("environments.md", "constraints.md", "scenarios.md")


@pytest.mark.parametrize("page", RUNNABLE_PAGES)
def test_page_examples_run(page, tmp_path, monkeypatch, capsys):
    """Every python block of the page runs as written, in order, in one namespace (files they
    write land in a temporary directory; ids they register are removed afterwards)."""
    import gymnasium as gym

    import jaxgrid
    from jaxgrid import registry

    blocks = _python_blocks((DOCS / page).read_text())
    assert blocks, page
    monkeypatch.chdir(tmp_path)
    before = set(jaxgrid.registered_ids())
    namespace = {"__name__": "__docs__"}
    try:
        for i, code in enumerate(blocks):
            needs = [m for m, used in (("minigrid", "from_minigrid"), ("gymnax", "jaxgrid.gymnax"))
                     if used in code and importlib.util.find_spec(m) is None]  # fmt: skip
            if needs:  # an optional extra that is not installed: that block only is skipped
                continue
            try:
                exec(compile(code, f"docs/{page} python block {i + 1}", "exec"), namespace)
            except Exception as e:  # the message names the block
                raise AssertionError(f"docs/{page}, python block {i + 1} failed: {e!r}\n{code}") \
                    from e  # fmt: skip
    finally:
        for env_id in set(jaxgrid.registered_ids()) - before:
            registry.unregister(env_id)
            gym.registry.pop(f"jaxgrid/{env_id}", None)
    if page == "environments.md":
        assert (tmp_path / "two_rooms.gif").stat().st_size > 0
        assert "##" in capsys.readouterr().out  # the ASCII map printed back


def _shown_commands() -> dict[str, set[str]]:
    """{module: flags shown after ``python -m module``} over the README and the pages."""
    shown: dict[str, set[str]] = {}
    for path in (ROOT / "README.md", *PAGES):
        for module, flags in gen_cli.commands_in(path.read_text()):
            shown.setdefault(module, set()).update(flags)
    return shown


def test_commands_are_found_in_the_text():
    text = "`python -m x.y --a 1 --b-c=2 # --not`\n```bash\npython -m z \\\n  --d && ls --e\n```\n"
    assert sorted(gen_cli.commands_in(text)) == [("x.y", ["--a", "--b-c"]), ("z", ["--d"])]
    shown = _shown_commands()
    assert {"experiments.two_rooms", "checker", "checker.memory", "pytest"} <= set(shown)
    assert "--dist" in shown["pytest"] and "--sweep" in shown["experiments.two_rooms"]


@pytest.fixture(scope="module")
def helps() -> dict[str, dict]:
    """{module: {"code", "output"}} of ``python -m module --help`` for every shown module,
    all run in one process (``docs/gen_cli.py help``)."""
    out = subprocess.run([sys.executable, str(DOCS / "gen_cli.py"), "help",
                          *sorted(_shown_commands())],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert out.returncode == 0, out.stderr[-4000:]
    return json.loads(out.stdout)


def _flags(text: str) -> set[str]:
    return set(re.findall(r"--[A-Za-z][\w-]*", text))


def test_every_command_shown_runs_with_help_and_knows_its_flags(helps):
    """Each module shown exits 0 with ``--help``, and each flag written after it in the README
    or the docs is in what it printed."""
    failed = {m: r["output"][-1500:] for m, r in helps.items() if r["code"] != 0}
    assert not failed, f"`python -m MODULE --help` failed: {failed}"
    unknown = {}
    for module, flags in _shown_commands().items():
        if flags - _flags(helps[module]["output"]):
            unknown[module] = sorted(flags - _flags(helps[module]["output"]))
    assert not unknown, (
        f"flags shown in the README or docs/*.md that --help does not list: {unknown}"
    )


def test_every_flag_in_the_docs_code_is_a_commands_flag(helps):
    """A flag written in code anywhere in the README or the docs, with or without its command
    (`--penalty-warmup 0.5` in a sentence), is a flag of one of the commands shown. Not ours:
    XLA's flags (``--xla_...``) and the lines of other programs (Slurm's ``srun``, the
    distributed test's worker script)."""
    known = set().union(*(_flags(r["output"]) for r in helps.values()))
    unknown: dict[str, set[str]] = {}
    for path in (ROOT / "README.md", *PAGES):
        for piece in gen_cli.code_pieces(path.read_text()):
            if re.match(r"\s*(srun|python tests/)", piece):
                continue
            for flag in _flags(piece) - known:
                if not flag.startswith("--xla_"):
                    unknown.setdefault(flag, set()).add(path.name)
    assert not unknown, f"flags that no command shown has: {unknown}"


def _commands_of_the_project() -> list[str]:
    """Every module of experiments/, checker/ and benchmarks/ that runs as a command (its
    ``__main__`` guard calls ``run_main``)."""
    found = []
    for package in ("experiments", "checker", "benchmarks"):
        for path in sorted((ROOT / package).glob("*.py")):
            tree = ast.parse(path.read_text())
            if any(isinstance(n, ast.If) and "__main__" in ast.unparse(n.test)
                   and "run_main" in ast.unparse(n) for n in tree.body):  # fmt: skip
                found.append(package if path.stem == "__main__" else f"{package}.{path.stem}")
    return found


def test_every_command_has_its_flag_table():
    """A new command gets a table in the command-line reference (or the experiments' one)."""
    tabled = set()
    for page in ("cli.md", "experiments.md"):
        for marker in re.findall(r"<!-- flags: ([\w. ]+?) -->", (DOCS / page).read_text()):
            tabled.update(marker.split())
    commands = set(_commands_of_the_project())
    assert {"checker", "experiments.two_rooms", "benchmarks.train_speed"} <= commands
    missing = sorted(commands - tabled)
    assert not missing, f"commands without a flag table in docs/cli.md: {missing}"
