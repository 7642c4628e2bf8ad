"""``python -m checker.memory``: ``python -m checker --kind memory``, with the same flags: a short
name for the memory kind's command line."""

from __future__ import annotations

import sys
from collections.abc import Sequence

from checker import __main__ as command
from checker import cli

PROG = "python -m checker.memory"


def main(argv: Sequence[str] | None = None) -> dict:
    """:func:`checker.__main__.main` of ``--kind memory`` and ``argv`` (default
    ``sys.argv[1:]``), its messages naming this command."""
    return command.main(["--kind", "memory", *(sys.argv[1:] if argv is None else argv)], PROG)


if __name__ == "__main__":
    cli.run_main(main, PROG)
