"""Every ``python -m benchmarks.<x>`` as typed: ``--help``, bad flags refused before any compile,
a missing optional peer reported as one line, Ctrl-C ending it with status 130 at once.

In-process checks (``main(argv)``) cover every module cheaply; subprocesses cover what only a
real command shows: :func:`checker.cli.run_main`'s one-line error and its exit on SIGINT, which
without it is a traceback and often a segfault while XLA compiles.
"""

from __future__ import annotations

import ast
import importlib
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from benchmarks import env_throughput
from benchmarks.cli import INSTALL

ROOT = Path(__file__).resolve().parents[2]
SOURCES = sorted((ROOT / "benchmarks").glob("*.py"))
# The modules that are commands: those with a main().
COMMANDS = sorted(
    p.stem for p in SOURCES
    if any(isinstance(n, ast.FunctionDef) and n.name == "main"
           for n in ast.parse(p.read_text()).body)
)  # fmt: skip


def test_the_commands_are_found():
    assert {"checker_cost", "env_throughput", "purejaxrl_ppo", "train_speed"} <= set(COMMANDS)
    assert "cli" not in COMMANDS


def _main_guard(tree: ast.Module) -> ast.If | None:
    for node in tree.body:
        if isinstance(node, ast.If) and ast.unparse(node.test) == "__name__ == '__main__'":
            return node
    return None


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: p.stem)
def test_a_command_runs_main_through_run_main_only(path):
    """The guard holds nothing but ``run_main(main, "python -m benchmarks.<x>")``: work done
    outside it would escape its handling of errors and Ctrl-C."""
    guard = _main_guard(ast.parse(path.read_text()))
    if path.stem not in COMMANDS:
        assert guard is None
        return
    assert guard is not None and len(guard.body) == 1 and not guard.orelse
    call = guard.body[0].value
    assert isinstance(call, ast.Call) and ast.unparse(call.func) in ("run_main", "cli.run_main")
    assert [ast.unparse(a) for a in call.args] == ["main", f"'python -m benchmarks.{path.stem}'"]


@pytest.mark.parametrize("name", COMMANDS)
def test_help_exits_0_under_the_command_name(name, capsys, compiles):
    module = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(SystemExit) as exc:
        module.main(["--help"])
    assert exc.value.code == 0
    assert f"usage: python -m benchmarks.{name}" in " ".join(capsys.readouterr().out.split())
    assert compiles == []


BAD_FLAGS = [
    ("checker_cost", ["--steps", "inf"], "--steps"),
    ("checker_cost", ["--repeats", "0"], "--repeats"),
    ("checker_cost", ["--envs", "64", "-1"], "--envs"),
    ("checker_cost", ["--env", "Nope-v0"], "--env"),
    ("compile_times", ["--budget", "inf"], "--budget"),
    ("compile_times", ["--budget", "nan"], "--budget"),
    ("compile_times", ["--num-envs", "inf"], "--num-envs"),
    ("compile_times", ["--repeats", "-1"], "--repeats"),
    ("env_throughput", ["--num-envs", "inf"], "--num-envs"),
    ("env_throughput", ["--steps", "1e12"], "--steps"),
    ("env_throughput", ["--seed", "-1"], "--seed"),
    ("env_throughput", ["--libs", "gym"], "--libs"),
    ("family_throughput", ["--num-envs", "0"], "--num-envs"),
    ("family_throughput", ["--steps", "0"], "--steps"),
    ("family_throughput", ["--repeats", "inf"], "--repeats"),
    ("family_throughput", ["--ids", "MiniGrid-Nope-v0"], "--ids"),
    ("hazard_checks", ["--episodes", "0"], "--episodes"),
    ("hazard_checks", ["--episodes", "inf"], "--episodes"),
    ("layout_fidelity", ["--resets", "inf"], "--resets"),
    ("layout_fidelity", ["--alpha", "nan"], "--alpha"),
    ("layout_fidelity", ["--seed", "-1"], "--seed"),
    ("purejaxrl_ppo", ["--num-envs", "-1"], "--num-envs"),
    ("purejaxrl_ppo", ["--seed", "inf"], "--seed"),
    ("purejaxrl_ppo", ["--timesteps", "3e9"], "--timesteps"),
    ("sweep_scaling", ["--num-envs", "inf"], "--num-envs"),
    ("sweep_scaling", ["--repeats", "0"], "--repeats"),
    ("sweep_scaling", ["--mode", "nope"], "--mode"),
    ("threads", ["--updates", "inf"], "--updates"),
    ("threads", ["--experiment", "nope"], "--experiment"),
    ("train_speed", ["--cell-dim", "inf"], "--cell-dim"),
    ("train_speed", ["--modes", "nope"], "--modes"),
    ("train_speed", ["--timesteps", "0"], "--timesteps"),
]


def test_every_command_has_bad_flag_cases():
    assert {name for name, _, _ in BAD_FLAGS} == set(COMMANDS)


@pytest.mark.parametrize(("name", "argv", "flag"), BAD_FLAGS, ids=lambda x: str(x))
def test_a_bad_flag_is_a_usage_error_naming_it(name, argv, flag, capsys, compiles):
    module = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(SystemExit) as exc:
        module.main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 2 and flag in err and f"python -m benchmarks.{name}" in err
    assert compiles == []


# A peer the command cannot run without: (module, argv, the peer).
NEEDS_PEER = [
    ("purejaxrl_ppo", [], "navix"),
    ("family_throughput", ["--num-envs", "4"], "navix"),
    ("train_speed", ["--modes", "none"], "navix"),
    ("layout_fidelity", ["--ids", "MiniGrid-Empty-5x5-v0"], "minigrid"),
    ("env_throughput", ["--libs", "navix", "xminigrid"], "navix"),
]


@pytest.mark.parametrize(("name", "argv", "peer"), NEEDS_PEER, ids=lambda x: str(x))
def test_a_missing_peer_is_an_import_error_with_the_install_command(
    name, argv, peer, monkeypatch, compiles
):
    for absent in ("navix", "xminigrid", "minigrid"):
        monkeypatch.setitem(sys.modules, absent, None)  # `import absent` now fails
    module = importlib.import_module(f"benchmarks.{name}")
    with pytest.raises(ImportError) as exc:
        module.main(argv)
    assert peer in str(exc.value) and INSTALL in str(exc.value)
    assert compiles == []


def test_the_throughput_comparison_skips_a_missing_peer_and_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "navix", None)
    logged = []
    report = env_throughput.run(["navix"], [1], 1, 1, 1, log=logged.append)
    assert report["results"] == [] and "navix" in report["skipped"]
    assert logged[0].startswith("[skip] navix") and INSTALL in logged[0]


def _command(name: str, *argv: str, cwd: Path, pythonpath: str = "", **env: str):
    """``python -m benchmarks.<name> argv`` started in ``cwd`` (stderr piped)."""
    env = {
        **os.environ,
        **env,
        "PYTHONPATH": os.pathsep.join(filter(None, (pythonpath, str(ROOT)))),
    }
    return subprocess.Popen(
        [sys.executable, "-m", f"benchmarks.{name}", *argv], cwd=cwd, env=env,
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip


def test_a_missing_peer_is_one_line_and_exit_2(tmp_path):
    shadow = tmp_path / "shadow"
    shadow.mkdir()
    (shadow / "navix.py").write_text("raise ImportError('navix is hidden from this test')\n")
    proc = _command("purejaxrl_ppo", cwd=tmp_path, pythonpath=str(shadow))
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 2, err
    (line,) = err.strip().splitlines()
    assert line.startswith("python -m benchmarks.purejaxrl_ppo: error: --env Navix-")
    assert "navix is hidden from this test" in line and INSTALL in line


# The smallest sizes; env_throughput's scan is long enough to be still running when signalled.
INTERRUPTED = [
    pytest.param("checker_cost", ["--envs", "1", "--steps", "1", "--repeats", "1"]),
    pytest.param(
        "env_throughput",
        ["--libs", "jaxgrid", "--num-envs", "1", "--steps", "100000", "--repeats", "3"],
    ),  # fmt: skip
    pytest.param("hazard_checks", ["--episodes", "1"], marks=pytest.mark.slow),
    pytest.param(
        "sweep_scaling",
        ["--agents", "1", "--updates", "1", "--repeats", "1", "--num-envs", "8"],
        marks=pytest.mark.slow,
    ),  # fmt: skip
    pytest.param(
        "threads", ["--seeds", "1", "--updates", "1", "--rounds", "1"], marks=pytest.mark.slow
    ),  # fmt: skip
]


@pytest.mark.parametrize(("name", "argv"), INTERRUPTED)
def test_ctrl_c_while_compiling_exits_130_at_once(name, argv, tmp_path):
    """SIGINT shortly after the first compile starts (JAX logs it; importing a benchmark
    compiles nothing, so ``main`` is running): exit status 130 within 10 s, no traceback."""
    proc = _command(name, *argv, cwd=tmp_path, JAX_LOG_COMPILES="1")
    lines, compiling = [], threading.Event()

    def read():
        for line in proc.stderr:
            lines.append(line)
            if line.startswith("Compiling "):
                compiling.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        compiling.wait(timeout=180)
        assert compiling.is_set(), "".join(lines)
        time.sleep(2.0)  # into the compiles of main's first programs
        assert proc.poll() is None, f"finished before it was interrupted:\n{''.join(lines)}"
        proc.send_signal(signal.SIGINT)
        start = time.monotonic()
        proc.wait(timeout=10)
        stopped_s = time.monotonic() - start
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=5)
    err = "".join(lines)
    assert proc.returncode == 130, err
    assert stopped_s < 10
    assert "Traceback" not in err and "Segmentation" not in err
    assert err.rstrip().endswith("interrupted")
