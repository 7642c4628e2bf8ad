"""Every ``python -m`` command of the project, started bare (no flags) from an empty directory,
as a new user would: it starts its work and Ctrl-C then ends it with exit status 130, or it
says what it needs (a flag, an optional peer) with exit status 2; never a traceback.

The experiments' own as-typed tests (``tests/experiments/test_as_typed.py``) follow them
further; this one covers every command, so it is slow (``-m slow``).
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from helpers import commands

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
    proc = commands.start(command, tmp_path, stdout=subprocess.PIPE)
    early, code, err = commands.interrupt(proc, 15)  # imports done, work begun (or refused)
    assert "Traceback" not in err and "Segmentation" not in err, err[-3000:]
    if early is not None:  # it needs an input (a flag, an optional peer) and says so
        assert early == 2 and ("error" in err.lower() or "required" in err), (early, err[-2000:])
    else:
        assert code == 130 and "interrupted" in err, (code, err[-2000:])
