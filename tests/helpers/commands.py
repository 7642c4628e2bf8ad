"""Starting the project's ``python -m`` commands as a user's shell would, for the tests that
send them Ctrl-C."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _default_sigint() -> None:
    # SIGINT as a terminal delivers it: a child of a non-interactive shell may inherit it
    # ignored (bash's `cmd &`), and the command would then never see Ctrl-C.
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start(command: str, cwd: Path, *args: str, stdout=subprocess.DEVNULL) -> subprocess.Popen:
    """``python -m command *args`` in ``cwd``, the repository on its path; stderr piped."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)}  # fmt: skip
    return subprocess.Popen([sys.executable, "-m", command, *args], cwd=cwd, env=env,
                            stdout=stdout, stderr=subprocess.PIPE,
                            preexec_fn=_default_sigint)  # fmt: skip


def interrupt(proc: subprocess.Popen, after_s: float, timeout_s: float = 10) -> tuple:
    """Send SIGINT ``after_s`` seconds after start unless ``proc`` has ended by then; return
    ``(status before the signal or None, final status, stderr text)``, killing it if it does
    not end within ``timeout_s`` of the signal (``subprocess.TimeoutExpired`` then)."""
    try:
        try:
            proc.wait(timeout=after_s)
        except subprocess.TimeoutExpired:
            pass
        early = proc.poll()
        if early is None:
            proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return early, proc.returncode, err.decode(errors="replace")
