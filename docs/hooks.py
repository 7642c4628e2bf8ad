"""MkDocs hook of the documentation site (``hooks:`` in ``mkdocs.yml``).

Markers in the pages are replaced when the site is built, so that what they show comes from
the code, not from a copy of it:

* ``<!-- flags: MODULE [MODULE ...] -->``: the flag tables of ``python -m MODULE --help``,
  built from the parser the command builds (``docs/gen_cli.py``): for the experiments, tyro's
  parser of the config dataclasses, with their defaults and help comments; one default
  column per module;
* ``<!-- api-if-exists: MODULE -->``: ``::: MODULE`` (mkdocstrings) when the module's source
  file exists, else nothing (a module that is still being written).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
for path in (str(DOCS), str(ROOT)):
    if path not in sys.path:
        sys.path.insert(0, path)

import gen_cli  # noqa: E402  (after the paths above)

FLAGS = re.compile(r"^<!-- flags: ([\w. ]+?) -->$", re.M)
API_IF_EXISTS = re.compile(r"^<!-- api-if-exists: ([\w.]+) -->$", re.M)
_tables: dict[tuple[str, ...], str] = {}


def _table(modules: tuple[str, ...]) -> str:
    if modules not in _tables:
        _tables[modules] = gen_cli.flags_table(list(modules))
    return _tables[modules]


def _source_exists(module: str) -> bool:
    path = ROOT.joinpath(*module.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def on_pre_build(config) -> None:
    _tables.clear()  # `mkdocs serve` rebuilds: read the parsers again


def on_page_markdown(markdown: str, page, config, files) -> str:
    markdown = FLAGS.sub(lambda m: _table(tuple(m.group(1).split())), markdown)
    return API_IF_EXISTS.sub(
        lambda m: f"::: {m.group(1)}" if _source_exists(m.group(1)) else "", markdown
    )
