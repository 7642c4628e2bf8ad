"""The project's command lines, read from the commands themselves.

Used by the documentation site's hook (``docs/hooks.py``: the flag tables of
``docs/cli.md`` are built from each command's parser when the site is built) and by
``tests/test_docs.py`` (every ``python -m ...`` the README and the docs show runs with
``--help``, and every flag shown after it is one of that command's flags).

* :func:`run` runs ``python -m MODULE ARGV`` in this process (``runpy``), returning its exit
  status and what it printed;
* :func:`parser` returns the ``argparse`` parser a command builds: the one tyro builds from
  the config dataclasses (:func:`checker.cli.parse`) or the one a benchmark builds itself;
* :func:`flags_table` renders parsers as Markdown tables: flags, help text and defaults;
* :func:`commands_in` finds the ``python -m MODULE --flag ...`` commands of a Markdown text.

``python docs/gen_cli.py help MODULE [MODULE ...]`` prints ``{module: {"code": status,
"output": text}}`` as JSON, each command run once with ``--help`` in one process.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import runpy
import signal
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


class _Captured(BaseException):
    """Carries a command's parser out of its ``main`` (not an ``Exception``: no ``except``
    of the command's catches it)."""

    def __init__(self, parser: argparse.ArgumentParser):
        super().__init__("parser captured")
        self.parser = parser


@contextlib.contextmanager
def _as_command(module: str, argv: list[str]):
    """``sys.argv`` as the command sees it, ``exit_now`` as a ``SystemExit`` (a command's
    exit must not end this process), and the SIGINT handler restored afterwards."""
    from jaxgrid import rundir

    saved_argv, saved_exit, saved_sigint = sys.argv, rundir.exit_now, None
    with contextlib.suppress(ValueError):  # not the main thread: no handler to restore
        saved_sigint = signal.getsignal(signal.SIGINT)

    def exit_now(code: int, wait_s: float = 5.0) -> None:
        raise SystemExit(code)

    sys.argv, rundir.exit_now = [module, *argv], exit_now
    try:
        yield
    finally:
        sys.argv, rundir.exit_now = saved_argv, saved_exit
        if saved_sigint is not None:
            signal.signal(signal.SIGINT, saved_sigint)


def run(module: str, argv: list[str]) -> tuple[int, str]:
    """``python -m module *argv`` in this process: ``(exit status, stdout + stderr)``."""
    out = io.StringIO()
    code = 0
    env_columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "120"  # tyro wraps its help to the terminal's width
    try:
        with _as_command(module, argv), contextlib.redirect_stdout(out), \
                contextlib.redirect_stderr(out):  # fmt: skip
            try:
                with warnings.catch_warnings():  # "found in sys.modules": run anyway
                    warnings.simplefilter("ignore", RuntimeWarning)
                    runpy.run_module(module, run_name="__main__", alter_sys=True)
            except SystemExit as e:
                code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
            except Exception as e:  # noqa: BLE001 - a broken command is reported, not raised
                print(f"{type(e).__name__}: {e}")
                code = 1
    finally:
        if env_columns is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = env_columns
    return code, out.getvalue()


def parser(module: str) -> argparse.ArgumentParser:
    """The parser ``python -m module`` parses its command line with.

    The command runs with ``--help`` until it asks for its command line to be parsed: a
    tyro command (:func:`checker.cli.parse`) hands over the parser tyro builds from the same
    config dataclasses and defaults, an argparse one the parser it built. Pre-parsers
    (``add_help=False``, such as the experiments' ``--quick``/``--paper`` one) are passed by.
    """
    import tyro
    import tyro.extras

    real_cli = tyro.cli
    parse_args = argparse.ArgumentParser.parse_args
    parse_known_args = argparse.ArgumentParser.parse_known_args

    def tyro_cli(f, *, args=None, prog=None, description=None, default=None, **kwargs):
        with warnings.catch_warnings():  # get_parser is deprecated in tyro 1.x, still there
            warnings.simplefilter("ignore", DeprecationWarning)
            built = tyro.extras.get_parser(f, prog=prog, description=description,
                                           default=default, **kwargs)  # fmt: skip
        raise _Captured(built)

    def capture(original):
        def parse(self, *args, **kwargs):
            if self.add_help:
                raise _Captured(self)
            return original(self, *args, **kwargs)

        return parse

    tyro.cli = tyro_cli
    argparse.ArgumentParser.parse_args = capture(parse_args)
    argparse.ArgumentParser.parse_known_args = capture(parse_known_args)
    try:
        with _as_command(module, ["--help"]), contextlib.redirect_stdout(io.StringIO()), \
                warnings.catch_warnings():  # fmt: skip
            warnings.simplefilter("ignore", RuntimeWarning)
            runpy.run_module(module, run_name="__main__", alter_sys=True)
    except _Captured as captured:
        return captured.parser
    finally:
        tyro.cli = real_cli
        argparse.ArgumentParser.parse_args = parse_args
        argparse.ArgumentParser.parse_known_args = parse_known_args
    raise RuntimeError(f"python -m {module} parsed no command line")


_DEFAULT = re.compile(r"\s*\(default: (.*)\)\s*$", re.S)
_REQUIRED = re.compile(r"\s*\(required\)\s*$")


def _entries(p: argparse.ArgumentParser) -> list[tuple[str, str, list[tuple[str, str, str]]]]:
    """``[(group title, group description, [(flags, help, default)])]`` of a parser."""
    formatter = p._get_formatter()
    groups = []
    for group in p._action_groups:
        rows = []
        for action in group._group_actions:
            if action.help == argparse.SUPPRESS or "--help" in action.option_strings:
                continue
            flags = ", ".join(action.option_strings) or action.dest
            text = formatter._expand_help(action) if action.help else ""
            default = ""
            found = _DEFAULT.search(text)
            if found:  # tyro appends "(default: X)" to the help
                text, default = text[: found.start()], found.group(1)
            elif _REQUIRED.search(text):  # ... or "(required)"
                text, default = text[: _REQUIRED.search(text).start()], "(required)"
            elif action.default not in (None, argparse.SUPPRESS) and action.option_strings and \
                    not type(action.default).__module__.startswith("tyro"):  # fmt: skip
                value = action.default
                if isinstance(value, list | tuple):
                    value = " ".join(str(v) for v in value)
                default = str(value)
            rows.append((flags, " ".join(text.split()), " ".join(default.split())))
        if rows:
            groups.append((group.title or "", " ".join((group.description or "").split()), rows))
    return groups


_LITERAL = re.compile(r"(``[^`|]+``|`[^`|]+`)")


def _cell(text: str) -> str:
    """Markdown table cell text: ``literals`` (RST) and `literals` as code, elsewhere
    HTML-like words kept and pipes and emphasis marks escaped."""
    out = []
    text = re.sub(r":\w+:`~?([^`]+)`", r"`\1`", text)  # :mod:`x` -> `x`
    for i, part in enumerate(_LITERAL.split(text)):
        if i % 2:
            out.append(f"`{part.strip('`')}`")
        else:
            part = part.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")
            out.append(re.sub(r"([|*_\\`\[\]])", r"\\\1", part))
    return "".join(out)


def _code(text: str) -> str:
    return f"`{text}`" if text else ""


def flags_table(modules: list[str]) -> str:
    """Markdown: one table per option group of ``python -m M --help``, for each ``M`` in
    ``modules``, with a default column per module (``-``: no such flag there)."""
    parsers = {m: parser(m) for m in modules}
    groups: dict[str, tuple[str, dict[str, tuple[str, dict[str, str]]]]] = {}
    for module, p in parsers.items():
        for title, description, rows in _entries(p):
            _, flags = groups.setdefault(title, (description, {}))
            for flag, text, default in rows:
                help_text, defaults = flags.setdefault(flag, (text, {}))
                defaults[module] = default
    if len(modules) == 1:
        about = (parsers[modules[0]].description or "").strip().split("\n\n")[0]
        lines = [_cell(" ".join(about.split())), ""] if about else []
        lines += [
            f"Flags of `python -m {modules[0]}`, read from its parser when this page was built:",
            "",
        ]
    else:
        lines = [
            "Read from the parsers of "
            + ", ".join(f"`python -m {m}`" for m in modules)
            + " when this page was built:",
            "",
        ]
    heads = ["default"] if len(modules) == 1 else [f"`{m.rsplit('.', 1)[-1]}`" for m in modules]
    for title, (description, flags) in groups.items():
        if len(groups) > 1 and title:
            lines += [f"**{_cell(title)}**" + (f": {_cell(description)}" if description else ""),
                      ""]  # fmt: skip
        lines.append("| flag | meaning | " + " | ".join(heads) + " |")
        lines.append("|---|---|" + "---|" * len(heads))
        for flag, (text, defaults) in flags.items():
            cells = [_code(defaults[m]) if m in defaults else "-" for m in modules]
            lines.append(f"| `{flag}` | {_cell(text)} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


# ----------------------------------------------------------------------------------------
# The commands a Markdown text shows
# ----------------------------------------------------------------------------------------
_FENCE = re.compile(r"^(```|~~~)[^\n]*\n(.*?)^\1[ \t]*$", re.M | re.S)
_SPAN = re.compile(r"(?<!`)`([^`]+)`(?!`)")
# a module name; a placeholder (``python -m MODULE``, ``experiments.<name>``) is none
_COMMAND = re.compile(r"python3? -m ([a-z_]\w*(?:\.[a-z_]\w*)*)(?![\w.<])")
_END = re.compile(r"&&|;|\s\|\s|\s#|\|\||$")
_FLAG = re.compile(r"(?<![\w-])--[A-Za-z][\w-]*")


def code_pieces(text: str) -> list[str]:
    """The code of a Markdown text: each line of its fenced blocks (``\\`` continuations
    joined) and each inline code span (line breaks inside a span read as spaces)."""
    pieces = []
    for block in _FENCE.finditer(text):
        pieces += block.group(2).replace("\\\n", " ").splitlines()
    prose = _FENCE.sub("", text)
    pieces += [" ".join(span.split()) for span in _SPAN.findall(prose)]
    return pieces


def commands_in(text: str) -> list[tuple[str, list[str]]]:
    """``[(module, flags)]`` of every ``python -m module ...`` in the code of ``text``: the
    long flags written after it, up to the end of the command (``&&``, ``;``, `` | ``, a
    comment or the next ``python -m``)."""
    found = []
    for piece in code_pieces(text):
        starts = list(_COMMAND.finditer(piece))
        for i, command in enumerate(starts):
            rest = piece[command.end() : starts[i + 1].start() if i + 1 < len(starts) else None]
            rest = rest[: _END.search(rest).start()]
            found.append((command.group(1), _FLAG.findall(rest)))
    return found


if __name__ == "__main__":
    if len(sys.argv) < 3 or sys.argv[1] != "help":
        raise SystemExit("usage: python docs/gen_cli.py help MODULE [MODULE ...]")
    results = {}
    for name in sys.argv[2:]:
        status, output = run(name, ["--help"])
        results[name] = {"code": status, "output": output}
    sys.stdout.write(json.dumps(results))
