"""Command-line pieces shared by the benchmarks' argparse parsers.

:func:`integer` and :func:`real` are argparse ``type=`` converters: a value that is not a
number, not finite or out of range is a usage error naming its flag (exit status 2) while the
command line is parsed, before anything is compiled, as :func:`checker.cli.parse` does for the
config-based commands. :func:`require` imports an optional peer (navix, xminigrid, minigrid):
one that does not import raises ``ImportError`` naming it and the install command, which
:func:`checker.cli.run_main` reports as one line and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import math
from types import ModuleType

from checker.cli import INT_MAX

#: How the optional peers are installed (``pyproject.toml``'s ``bench`` extra).
INSTALL = 'pip install -e ".[bench]"'


def integer(text: str) -> int:
    """An integer flag's value (``1e6`` accepted), at most :data:`checker.cli.INT_MAX` in size:
    sizes, counts and seeds become array shapes and 32-bit PRNG keys."""
    try:
        value = int(text) if text.strip().lstrip("+-").isdigit() else float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if isinstance(value, float) and (not math.isfinite(value) or value != int(value)):
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer")
    if abs(value) > INT_MAX:
        raise argparse.ArgumentTypeError(f"{text!r} is out of range (at most {INT_MAX} in size)")
    return int(value)


def real(text: str) -> float:
    """A finite float flag's value: ``inf`` or ``nan`` would pass every range check unnoticed."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def require(module: str, needed_by: str, instead: str | None = None) -> ModuleType:
    """``module`` imported; where it does not import (not installed, or broken against this
    JAX), ``ImportError`` saying that ``needed_by`` needs it, how to install it and, if given,
    what to do ``instead``."""
    try:
        return importlib.import_module(module)
    except Exception as e:  # an incompatible peer fails with other errors than ImportError
        alternative = f", or {instead}" if instead else ""
        raise ImportError(
            f"{needed_by} needs {module}, which does not import here ({type(e).__name__}: {e}); "
            f"install the benchmarks' peers with: {INSTALL}{alternative}"
        ) from e
