"""Run directories: one writer at a time, and checksums that tell a damaged file from a good one.

- :func:`lock` / :class:`RunLock`: ``DIR/.lock``, created with ``O_CREAT | O_EXCL`` and
  holding the owner's pid and host, is taken before a command writes into ``DIR`` and removed
  when it stops (normally, on an exception or on Ctrl-C). A second process gets
  :class:`LockHeld` at once, naming the holder. A lock left by a dead process of this host (its
  pid no longer runs) is taken over, with a message on stderr; a lock of another host is never
  taken over, since its pid cannot be checked from here.
- :func:`sha256_bytes` / :func:`sha256_file`: the digest recorded in a parameter file's JSON
  sidecar and checked when the file is loaded, so a truncated or bit-flipped file is refused
  instead of loading as different numbers.
- :func:`interruptible`, :func:`writing`, :func:`exit_now`: a command interrupted by Ctrl-C
  leaves within seconds, at any point, without
  waiting for a compile or a training chunk in another thread (and without the interpreter's
  teardown, which can crash under a running XLA computation), but never in the middle of a
  write made under :func:`writing`; the run locks it holds are released first.
- :func:`prepare_command`: what a ``python -m`` command does before jax loads (Ctrl-C
  handling, a held ``--out`` refused).

Standard library only.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import signal
import socket
import sys
import threading
from pathlib import Path

__all__ = ["LOCK_FILE", "LockHeld", "RunLock", "check_free", "exit_now", "interruptible",
           "interrupted_message", "lock", "out_flag", "prepare_command", "refuse_held_out",
           "sha256_bytes", "sha256_file", "writing"]  # fmt: skip

LOCK_FILE = ".lock"
# Held while an artefact is written that a partial write would damage (a checkpoint and the
# digests recorded beside it); exit_now waits for it. Re-entrant: a save may nest writes.
_WRITING = threading.RLock()
_HELD: set[RunLock] = set()  # the run locks this process holds, released by exit_now


_WATCHING = threading.Event()  # interruptible() has run


@contextlib.contextmanager
def writing():
    """Hold the process's write lock for the block: Ctrl-C and :func:`exit_now` wait for it."""
    with _WRITING:
        yield


def _leave() -> None:
    print("\n" + interrupted_message(), file=sys.stderr)
    exit_now(130)


def _watch() -> None:
    signal.sigwait({signal.SIGINT})
    threading.Thread(target=_leave, name="leaving", daemon=True).start()
    signal.sigwait({signal.SIGINT})  # a second Ctrl-C while writes finish: leave now
    os._exit(130)


def interruptible() -> None:
    """Make Ctrl-C end this process (a command's) with status 130 through :func:`exit_now`,
    after the writes in progress (:func:`writing`), saying which run directories hold the
    finished work and the commands that resume them. A second Ctrl-C leaves at once.

    SIGINT is blocked in every thread (threads started later inherit the mask) and taken by a
    watcher thread with ``sigwait``, so it acts even while the main thread sits in a long
    compile or computation, where a Python signal handler would wait for it to return. No
    ``KeyboardInterrupt`` is raised: Python ignores one raised inside a garbage-collector
    callback (jax runs one at every collection), and one raised inside an import can come out
    as another error. Call it from the main thread before other threads start.
    """
    if _WATCHING.is_set():
        return
    _WATCHING.set()
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    threading.Thread(target=_watch, name="ctrl-c", daemon=True).start()


def out_flag(argv: list[str]) -> str | None:
    """The value of ``--out`` in ``argv`` (``--out DIR`` or ``--out=DIR``; the last one wins,
    as with argparse), or None."""
    out = None
    for i, a in enumerate(argv):
        if a == "--out":
            out = argv[i + 1] if i + 1 < len(argv) else None
        elif a.startswith("--out="):
            out = a.split("=", 1)[1]
    return out or None


def refuse_held_out(argv: list[str]) -> None:
    """Exit with status 2, naming the holder, when a live process holds the lock of
    ``argv``'s ``--out`` (:func:`check_free`); before the flags are parsed, so a second run on
    a directory is refused at once."""
    out = out_flag(argv)
    try:
        if out:
            check_free(out)
    except LockHeld as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None


def prepare_command() -> None:
    """When the importing package is being run as ``python -m <package>.<command>``
    (``sys.argv[0]`` is ``"-m"`` while Python imports it): :func:`interruptible`, and
    :func:`refuse_held_out` on the command's flags. A library import changes nothing. Called
    first thing by the command packages, so that Ctrl-C is handled from the first second and
    a held ``--out`` is refused before jax loads (which takes seconds)."""
    if sys.argv[:1] == ["-m"] and threading.current_thread() is threading.main_thread():
        interruptible()
        refuse_held_out(sys.argv[1:])


def interrupted_message() -> str:
    """``interrupted``, and for each run directory held with a resume command, where the
    finished work is and the command that resumes it."""
    lines = ["interrupted"]
    for held in sorted(_HELD, key=lambda h: str(h.directory)):
        if held.resume:
            lines.append(f"finished work is kept in {held.directory}; resume with\n  "
                         f"{held.resume}")  # fmt: skip
    return "\n".join(lines)


def exit_now(code: int, wait_s: float = 5.0) -> None:
    """End the process with status ``code`` at once: wait up to ``wait_s`` for a write under
    :func:`writing` to finish, release the run locks held, flush stdout and stderr, then
    ``os._exit`` (no interpreter teardown, no waiting for other threads)."""
    _WRITING.acquire(timeout=wait_s)  # kept until the process ends: no write starts now
    for held in list(_HELD):
        with contextlib.suppress(OSError):
            held.release()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


class LockHeld(RuntimeError):
    """Another live process writes into the run directory."""


def sha256_bytes(data: bytes) -> str:
    """Hex SHA-256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of the file at ``path``."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return True
    return True


class RunLock:
    """The lock of one run directory; a context manager (see :func:`lock`)."""

    def __init__(self, directory: str | os.PathLike, what: str = "run",
                 resume: str | None = None):  # fmt: skip
        self.directory = Path(directory)
        self.path = self.directory / LOCK_FILE
        self.what = what
        self.resume = resume  # the command that resumes the run (named on Ctrl-C)
        self.held = False

    def acquire(self) -> RunLock:
        """Take the lock; ``LockHeld`` naming the holder if a live process has it.

        ``ValueError`` if the directory cannot be created (e.g. it is a file)."""
        if self.directory.exists() and not self.directory.is_dir():
            raise ValueError(f"{self.directory} is a file, not a directory")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ValueError(f"{self.directory}: not writable ({e.strerror or e})") from None
        me = {"pid": os.getpid(), "host": socket.gethostname(), "what": self.what}
        for _ in range(3):  # a stale lock is removed, then created again
            try:
                fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is None:  # released meanwhile: try again
                    continue
                if not self._stale(holder):
                    raise LockHeld(self._held_message(holder)) from None
                print(f"{self.path}: taking over the lock of {self._who(holder)}, which no "
                      "longer runs", file=sys.stderr)  # fmt: skip
                self.path.unlink(missing_ok=True)
                continue
            except OSError as e:
                if e.errno in (errno.EACCES, errno.EROFS, errno.EPERM):
                    raise ValueError(f"{self.directory}: not writable ({e.strerror})") from None
                raise
            with os.fdopen(fd, "w") as f:
                json.dump(me, f)
            self.held = True
            _HELD.add(self)
            return self
        raise LockHeld(self._held_message(self._holder()))

    def release(self) -> None:
        """Remove the lock file if this object holds it."""
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False
            _HELD.discard(self)

    def __enter__(self) -> RunLock:
        return self if self.held else self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()

    def _holder(self) -> dict | None:
        try:
            holder = json.loads(self.path.read_text())
            return holder if isinstance(holder, dict) else {}
        except FileNotFoundError:
            return None
        except (OSError, ValueError):
            return {}  # being written right now, or damaged: its owner is unknown

    @staticmethod
    def _stale(holder: dict) -> bool:
        pid = holder.get("pid")
        if holder.get("host") != socket.gethostname() or not isinstance(pid, int):
            return False
        return not _alive(pid)

    @staticmethod
    def _who(holder: dict | None) -> str:
        if not holder:
            return "an unknown process"
        return f"{holder.get('what', 'a run')} pid {holder.get('pid')} on {holder.get('host')}"

    def _held_message(self, holder: dict | None) -> str:
        return (f"{self.directory} is in use by {self._who(holder)} (lock file {self.path}); "
                "wait for it, pick another directory, or delete the lock file if that process "
                "is gone")  # fmt: skip


def check_free(directory: str | os.PathLike) -> None:
    """Raise :class:`LockHeld` if a live process holds the lock of ``directory``; creates and
    writes nothing, so a command can refuse at once, before it parses or imports more."""
    run = RunLock(directory)
    holder = run._holder() if run.path.is_file() else None
    if holder is not None and not run._stale(holder):
        raise LockHeld(run._held_message(holder))


def lock(directory: str | os.PathLike, what: str = "run", resume: str | None = None) -> RunLock:
    """Take the lock of ``directory`` (created if missing) for a process writing into it.

    Use as ``with lock(out, "python -m checker"): ...``: released on any exit of the block.
    Raises :class:`LockHeld` (naming the holder's pid and host) when a live process holds it.
    """
    return RunLock(directory, what, resume).acquire()
