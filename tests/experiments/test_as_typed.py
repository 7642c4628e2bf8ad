"""Every experiment command exactly as a user types it: no flags, from an empty directory.

Each one is started as a subprocess, watched until it is visibly training, then sent Ctrl-C:
it must leave within 10 s with exit status 130, no traceback, and the command that resumes.
The README's first command (``experiments.two_rooms``) is followed to its first finished
training chunk; the others to their first training phase's progress bar (Ctrl-C then lands
while XLA compiles, the moment that once crashed the interpreter), and to their first
finished chunk under ``-m slow``.
"""

from __future__ import annotations

import re
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
from helpers import commands

# The child resets SIGINT between fork and exec (one signal call, no lock taken).
pytestmark = pytest.mark.filterwarnings("ignore:os.fork\\(\\) was called:RuntimeWarning")
# A progress bar of a phase that trains: "a. behaviour agent:  0%| 0/18" (the window
# checker's experiments) or the memory checker's streams and fit (HazardRooms).
STARTED = re.compile(r"(a\. behaviour agent|memory checker|streams)[^\n\r]*\|")
# ... and one of its chunks done: "1/18 [...]"
CHUNK = re.compile(r"(a\. behaviour agent|memory checker)[^\n\r]*\| *[1-9]\d*/\d+")


class Output:
    """A process's stderr, read in a thread so that the pipe never fills."""

    def __init__(self, proc: subprocess.Popen):
        self.text, self.proc = "", proc
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        for block in iter(lambda: self.proc.stderr.read1(4096), b""):
            self.text += block.decode(errors="replace")

    def wait_for(self, pattern: re.Pattern, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if pattern.search(self.text):
                return True
            if self.proc.poll() is not None:
                return bool(pattern.search(self.text))
            time.sleep(0.2)
        return False


def _start_then_interrupt(module: str, cwd: Path, until: re.Pattern, timeout: float) -> str:
    proc = commands.start(f"experiments.{module}", cwd)
    out = Output(proc)
    try:
        seen = out.wait_for(until, timeout)
        assert proc.poll() is None, f"exited {proc.returncode} before training:\n{out.text}"
        assert seen, f"not visibly training after {timeout:.0f} s:\n{out.text[-3000:]}"
        proc.send_signal(signal.SIGINT)
        sent = time.monotonic()
        code = proc.wait(timeout=30)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    out.thread.join(timeout=5)
    assert code == 130, f"exit status {code} after Ctrl-C:\n{out.text[-3000:]}"
    assert took <= 10, f"took {took:.1f} s to leave after Ctrl-C"
    assert "Traceback" not in out.text, out.text[-3000:]
    return out.text


def _check_resume_hint(module: str, text: str, cwd: Path) -> None:
    runs = sorted((cwd / "runs" / module).iterdir())
    assert len(runs) == 1, runs
    hint = f"python -m experiments.{module} --out runs/{module}/{runs[0].name}"
    assert hint in text, text[-2000:]
    assert not (runs[0] / ".lock").exists(), "the run lock outlived the run"


def test_readme_line_1_trains_then_stops_cleanly(tmp_path):
    """``python -m experiments.two_rooms``, bare: its first training chunk finishes."""
    text = _start_then_interrupt("two_rooms", tmp_path, CHUNK, timeout=240)
    _check_resume_hint("two_rooms", text, tmp_path)


# TwoRoomsLava and ThreeRoomsKey start as TwoRooms does above (the same phases); HazardRooms
# collects its memory checker's streams (a long compile) before its first bar: all three
# under -m slow, with the chunk tests below.
@pytest.mark.slow
@pytest.mark.parametrize("module", ["two_rooms_lava", "three_rooms_key", "hazard_rooms"])
def test_bare_experiment_starts_training_then_stops_cleanly(module, tmp_path):
    text = _start_then_interrupt(module, tmp_path, STARTED, timeout=120)
    _check_resume_hint(module, text, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("module", ["two_rooms_lava", "three_rooms_key", "hazard_rooms"])
def test_bare_experiment_trains_then_stops_cleanly(module, tmp_path):
    text = _start_then_interrupt(module, tmp_path, CHUNK, timeout=240)
    _check_resume_hint(module, text, tmp_path)


@pytest.mark.parametrize("delay", [0.5, 2.0])
def test_ctrl_c_while_the_command_still_imports_leaves_cleanly(delay, tmp_path):
    """Before jax has loaded, Python can swallow a KeyboardInterrupt (in a garbage-collector
    callback) or turn it into an ImportError; the command must still leave at once."""
    proc = commands.start("experiments.two_rooms", tmp_path)
    _, code, err = commands.interrupt(proc, delay)
    assert code == 130, err[-2000:]
    assert "Traceback" not in err and "interrupted" in err, err[-2000:]
