"""Which code made a run directory's artefacts: a digest of the sources and the versions.

An experiment's phases resume from the artefacts already in ``--out`` when the configuration
matches. The configuration does not say which code made them: a directory resumed after the
code changed holds a behaviour agent, data or checker that the current code would not make,
and its results cannot be reproduced from a fresh directory. :func:`record` keeps
``code.json`` in ``--out``, the identity of every code that wrote there, and says so on
stderr when a resume brings another one; ``results.json`` carries the list (``code``), and
``results.md`` warns when it holds more than one entry.
"""

from __future__ import annotations

import datetime
import hashlib
import importlib.metadata
import subprocess
import sys
from pathlib import Path

from jaxgrid.io import read_json, write_json

#: The packages whose sources make the artefacts.
PACKAGES = ("jaxgrid", "checker", "agents", "experiments")
#: Distributions whose versions change the numbers.
DISTRIBUTIONS = ("jax", "jaxlib", "flax", "optax", "numpy")
ROOT = Path(__file__).resolve().parent.parent


def code_identity() -> dict:
    """``{"sha256", "versions", "git"}``: a digest of every ``.py`` file of :data:`PACKAGES`
    (relative path and bytes, sorted), the installed versions of :data:`DISTRIBUTIONS`, and
    the git commit when the sources are a checkout (``None`` otherwise; ``+dirty`` when
    tracked files differ from it)."""
    digest = hashlib.sha256()
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            digest.update(str(path.relative_to(ROOT)).encode() + b"\0" + path.read_bytes())
    versions = {}
    for name in DISTRIBUTIONS:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    return {"sha256": digest.hexdigest(), "versions": versions, "git": _git_commit()}


def _git_commit() -> str | None:
    def git(*args):
        return subprocess.run(("git", "-C", str(ROOT), *args), capture_output=True, text=True,
                              timeout=10, check=True).stdout.strip()  # fmt: skip

    try:
        commit = git("rev-parse", "HEAD")
        dirty = bool(git("status", "--porcelain", "--untracked-files=no"))
    except (OSError, subprocess.SubprocessError):
        return None
    return commit + ("+dirty" if dirty else "")


def record(out: Path) -> list[dict]:
    """Add this code's identity to ``out/code.json`` unless it is already the last entry;
    return every entry. Warns on stderr when the directory already holds another code's."""
    path = out / "code.json"
    entries = read_json(path) if path.exists() else []
    mine = code_identity()
    if entries:
        last = entries[-1]
        if (last["sha256"], last["versions"]) == (mine["sha256"], mine["versions"]):
            return entries
        print(
            f"warning: --out {out} holds phases made by other code ({path}: "
            f"{last['sha256'][:12]}, now {mine['sha256'][:12]}). They are kept; its "
            "results will say so. For results one code made, use a fresh --out.",
            file=sys.stderr,
        )
    stamp = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    entries.append({**mine, "first_used": stamp})
    write_json(path, entries)
    return entries
