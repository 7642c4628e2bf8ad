"""Every ``python -m`` command of the project, started bare (no flags) from an empty directory,
as a new user would: it starts its work and Ctrl-C then ends it with exit status 130, or it
says what it needs (a flag, an optional peer) with exit status 2; never a traceback.

The experiments' own as-typed tests (``tests/experiments/test_as_typed.py``) follow them
further; this one covers every command, so it is slow (``-m slow``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("benchmarks", "checker", "experiments")


def _commands() -> list[str]:
    found = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).glob("*.py")):
            if 'if __name__ == "__main__":' in path.read_text():
                name = package if path.stem == "__main__" else f"{package}.{path.stem}"
                found.append(name)
    return found


COMMANDS = _commands()
pytestmark = pytest.mark.filterwarnings("ignore:os.fork\\(\\) was called:RuntimeWarning")


def test_every_command_is_found():
    assert len(COMMANDS) >= 20 and "experiments.two_rooms" in COMMANDS and "checker" in COMMANDS


@pytest.mark.slow
@pytest.mark.parametrize("command", COMMANDS)
def test_bare_command_starts_then_stops_cleanly(command, tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    default_sigint = lambda: signal.signal(signal.SIGINT, signal.SIG_DFL)  # noqa: E731
    proc = subprocess.Popen([sys.executable, "-m", command], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            preexec_fn=default_sigint)  # fmt: skip
    try:
        time.sleep(15)  # imports done, work (or its refusal) begun
        early = proc.poll()
        if early is None:
            proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    err = err.decode(errors="replace")
    assert "Traceback" not in err and "Segmentation" not in err, err[-3000:]
    if early is not None:  # it needs an input (a flag, an optional peer) and says so
        assert early == 2 and ("error" in err.lower() or "required" in err), (early, err[-2000:])
    else:
        assert proc.returncode == 130 and "interrupted" in err, (proc.returncode, err[-2000:])
