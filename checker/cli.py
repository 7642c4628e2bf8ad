"""Command lines generated from frozen dataclasses, for ``python -m checker``,
``python -m benchmarks.checker_cost`` and ``python -m experiments.<name>``.

:func:`parse` builds the parser with tyro from the fields of a config and of the configs it
nests: every field is one flat flag (``--field-name``, or the name given in ``names``; ``None``
hides it) whose ``--help`` shows its default, so a setting is declared once, where its config
declares it. Ints also accept ``1e6``. A config validates itself on construction; its
``ValueError`` names ``Class.field``, which the command line replaces with the flag and reports
as a usage error (exit status 2), before anything is compiled. Unknown flags and values of the
wrong type are tyro's usage errors, also exit status 2.

:func:`run_main` is how every ``python -m ...`` of this project runs its ``main``: a user's
mistake (a bad flag value, path or artefact, a missing optional dependency) is one line and
exit status 2, Ctrl-C is exit status 130 at once; a bug keeps its traceback.
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import math
import os
import re
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Annotated, NoReturn, TypeVar

import tyro
from tyro.constructors import (
    MISSING_NONPROP,
    ConstructorRegistry,
    PrimitiveConstructorSpec,
    StructConstructorSpec,
    StructTypeInfo,
)

from checker.protocol import LABEL_LOOKAHEADS

T = TypeVar("T")
Names = Mapping[type, Mapping[str, str | None]]


class _Invalid(Exception):
    """A config rejected its values: a usage error."""


# Integer flags (seeds, sizes, step budgets) are at most this: a seed becomes a 32-bit PRNG
# key, and no size of this project comes near it.
INT_MAX = 2**31 - 1


def _int(args: list[str]) -> int:
    text = args[0]
    try:
        value = int(text) if text.lstrip("+-").isdigit() else float(text)  # accepts 1e6
    except ValueError:
        raise ValueError(f"{text!r} is not an integer") from None
    if isinstance(value, float) and (not math.isfinite(value) or value != int(value)):
        raise ValueError(f"{text!r} is not an integer")
    if abs(value) > INT_MAX:
        raise ValueError(f"{text!r} is out of range (at most {INT_MAX} in size)")
    return int(value)


def _registry(names: Names) -> ConstructorRegistry:
    registry = ConstructorRegistry()
    building: set[type] = set()  # types whose default spec is being asked for
    shown: dict[str, str] = {}  # "Class.field" -> "--flag", of every config of the parser

    @registry.primitive_rule
    def integers(info):
        if info.type is not int:
            return None
        return PrimitiveConstructorSpec(
            nargs=1, metavar="INT", instance_from_str=_int,
            is_instance=lambda x: isinstance(x, int) and not isinstance(x, bool),
            str_from_instance=lambda x: [str(x)],
        )  # fmt: skip

    @registry.struct_rule
    def flat(info: StructTypeInfo):
        cls = info.type
        if not dataclasses.is_dataclass(cls) or cls in building:
            return None
        building.add(cls)
        try:  # tyro's own spec of the dataclass, then renamed and flattened
            spec = ConstructorRegistry.get_struct_spec(info)
        finally:
            building.discard(cls)
        if not isinstance(spec, StructConstructorSpec):
            return spec
        renames = names.get(cls, {})
        fields = []
        for f in spec.fields:
            flag = renames.get(f.name, f.name)
            if flag is None:
                kind = tyro.conf.Suppress[f.type]
            else:
                flag = flag.replace("_", "-")
                kind = Annotated[f.type, tyro.conf.arg(name=flag, prefix_name=False)]
                shown[f"{cls.__name__}.{f.name}"] = f"--{flag}"
            fields.append(dataclasses.replace(f, type=kind))

        def instantiate(**kwargs):
            try:
                return spec.instantiate(**kwargs)
            except ValueError as e:  # past tyro, which reports these unevenly across versions
                raise _Invalid(flag_names(str(e), shown)) from None

        return StructConstructorSpec(instantiate=instantiate, fields=tuple(fields))

    return registry


def flag_names(message: str, flags: Mapping[str, str]) -> str:
    """``message`` with each ``Class.field`` in ``flags`` replaced by its ``--flag``."""
    return re.sub(r"\b\w+\.\w+\b", lambda m: flags.get(m.group(0), m.group(0)), message)


def parse(
    cls: type[T],
    argv: Sequence[str] | None = None,
    *,
    default: T | None = None,
    prog: str | None = None,
    description: str | None = None,
    names: Names | None = None,
    title: str | None = None,
) -> T:
    """``cls`` from the command line ``argv`` (default ``sys.argv[1:]``) over ``default``.

    ``names[C][field]`` is the flag of a field of config ``C`` (dashes for underscores;
    ``None``: no flag, the default stays); other fields are flags of their own name, nested
    configs included; ``--help`` shows each nested config's flags in a group of its own and
    ``cls``'s in one titled ``title options`` (tyro's plain ``options`` without a title).
    ``--help`` and usage errors exit (status 0 and 2).
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    shown = _Shown(sys.stdout) if title and {"-h", "--help"} & set(argv) else None
    try:
        with _registry(names or {}), contextlib.redirect_stdout(shown or sys.stdout):
            return tyro.cli(cls, args=argv, prog=prog, description=description,
                            default=MISSING_NONPROP if default is None else default)  # fmt: skip
    except _Invalid as e:
        usage_error(str(e), prog)
    finally:
        if shown is not None:
            print(_titled(shown.getvalue(), title), end="")


def _titled(text: str, title: str) -> str:
    """``text`` of tyro's help with its root group ``options`` titled ``title options``, in a
    box (or over a rule) as wide as before; colour codes, where drawn, are kept."""
    plain = re.compile(r"\x1b\[[0-9;]*m")
    lines = text.split("\n")
    for i, line in enumerate(lines):
        bare = plain.sub("", line)
        if not (bare.startswith("╭─ options ") or bare.rstrip() == " options"):
            continue
        wide = line.replace("options", f"{title} options", 1)
        extra = len(title) + 1
        for pad in ("─", " "):  # the box's trailing rule, or the plain title's padding
            cut = wide.rfind(pad * extra)
            if cut >= 0 and (pad == "─" or bare.startswith(" options")):
                wide = wide[:cut] + wide[cut + extra :]
                break
        lines[i] = wide
        break
    return "\n".join(lines)


class _Shown(io.StringIO):
    """What tyro prints, kept: it draws as it would on ``stream`` (boxes, colours)."""

    def __init__(self, stream):
        super().__init__()
        self._stream = stream

    @property
    def encoding(self):
        return getattr(self._stream, "encoding", None)

    def isatty(self) -> bool:
        return self._stream.isatty()


def usage_error(message: str, prog: str | None = None) -> NoReturn:
    """Print ``message`` as a usage error of ``prog`` and exit with status 2."""
    prog = prog or os.path.basename(sys.argv[0])
    print(f"usage: {prog} [-h] [OPTIONS]\nerror: {message}\n(`{prog} --help` lists every flag "
          "and its default)", file=sys.stderr)  # fmt: skip
    raise SystemExit(2) from None


def label_flags(argv: Sequence[str], old: str, new: str, prog: str | None = None) -> list[str]:
    """``argv`` with the memory checker's former label-timing flag ``old next|into`` read as
    ``new 1|0`` (:data:`checker.protocol.LABEL_LOOKAHEADS`), so that command lines written
    before it was named ``lookahead`` keep working; another value is a usage error."""
    out, args = [], list(argv)
    while args:
        arg = args.pop(0)
        if arg != old and not arg.startswith(old + "="):
            out.append(arg)
            continue
        value = arg[len(old) + 1 :] if "=" in arg else (args.pop(0) if args else "")
        if value not in LABEL_LOOKAHEADS:
            usage_error(f"{old} must be one of {tuple(LABEL_LOOKAHEADS)} (the former name of "
                        f"{new}: {LABEL_LOOKAHEADS}), got {value!r}", prog)  # fmt: skip
        out += [new, str(LABEL_LOOKAHEADS[value])]
    return out


# What a user's mistake raises: shown as one line, exit status 2. ImportError: an optional
# dependency (navix, xminigrid, minigrid) that is not installed.
USER_ERRORS = (ValueError, OSError, ImportError)


def run_main(main: Callable[[], object], prog: str | None = None) -> NoReturn:
    """Run ``main()`` as a command and end the process.

    ``SystemExit`` keeps its status; a :data:`USER_ERRORS` exception prints ``error: ...``
    and exits with 2 (``JAXGRID_TRACEBACK=1`` re-raises it, for debugging). Ctrl-C is taken by
    :func:`jaxgrid.rundir.interruptible` (exit 130 within seconds, at any point); a
    ``KeyboardInterrupt`` that ``main`` raises itself, or its ``SystemExit(130)``, also leaves
    through :func:`jaxgrid.rundir.exit_now`, with no interpreter teardown, which can crash
    while XLA still compiles or runs in another thread.
    """
    from jaxgrid.rundir import LockHeld, exit_now, interruptible

    prog = prog or os.path.basename(sys.argv[0])
    interruptible()
    try:
        main()
    except KeyboardInterrupt:
        print("\ninterrupted", file=sys.stderr)
        exit_now(130)
    except SystemExit as e:
        if e.code == 130:  # main said what was kept; leave without waiting for threads
            exit_now(130)
        raise
    except (*USER_ERRORS, LockHeld) as e:
        if os.environ.get("JAXGRID_TRACEBACK"):
            raise
        print(f"{prog}: error: {e}", file=sys.stderr)
        exit_now(2)
    raise SystemExit(0)
