"""Crash-safe file writes and JSON / JSON-lines reading, for the whole repository.

- :func:`atomic_write`: a reader sees the old file or the whole new one, never half of it.
- :func:`write_json` / :func:`read_json`: one JSON document; numpy and JAX values become plain
  numbers and lists (:func:`to_jsonable`); a damaged file raises a ``ValueError`` naming it.
- :func:`write_jsonl` / :func:`append_jsonl` / :func:`read_jsonl`: one JSON record per line.
  Appending is not atomic, so a crash can leave a torn last line: the reader drops it and the
  next append cuts it off; a damaged line anywhere else raises, naming the file and line.

Only the standard library and numpy are imported: JAX arrays are recognised by their
``__array__`` method, so ``import jaxgrid.io`` starts no JAX backend.
"""

from __future__ import annotations

import dataclasses
import json
import math
import numbers
import os
import uuid
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "append_jsonl",
    "atomic_write",
    "read_json",
    "read_jsonl",
    "to_jsonable",
    "write_json",
    "write_jsonl",
]


def atomic_write(path: str | os.PathLike, data: bytes | str) -> Path:
    """Write ``data`` (``str`` is UTF-8 encoded) to ``path`` atomically; returns the path.

    The bytes go to a temporary file in the same directory (so the rename cannot cross file
    systems), are flushed and fsynced, then ``os.replace`` moves them over ``path``. On any
    error the temporary file is removed and ``path`` is untouched. Missing parent directories
    are created; the new file gets the usual umask-derived permissions.
    """
    path = Path(path)
    if isinstance(data, str):
        data = data.encode("utf-8")
    elif not isinstance(data, bytes | bytearray | memoryview):
        raise TypeError(f"{path}: data must be bytes or str, got {type(data).__name__}")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:12]}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)
    return path


def _fsync_dir(directory: Path) -> None:
    """Make the rename itself durable where the platform allows opening a directory."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def to_jsonable(x: Any, *, name: str = "value") -> Any:
    """``x`` as plain JSON types: strict JSON, so non-finite floats become ``None``.

    Mappings become dicts with ``str`` keys, tuples and lists become lists, numpy/JAX arrays
    (anything with ``__array__``) and numpy scalars become nested lists / numbers, ``bool``
    stays ``bool``, paths become strings. Any other type raises ``TypeError`` naming its place,
    e.g. ``value.config.schedule`` or ``value[3].loss`` (``name`` is the root's name).
    """
    return _convert(x, name)


def _convert(x: Any, where: str) -> Any:
    if x is None or isinstance(x, str):
        return x
    if isinstance(x, bool | np.bool_):
        return bool(x)
    if isinstance(x, numbers.Integral):
        return int(x)
    if isinstance(x, numbers.Real):
        f = float(x)
        return f if math.isfinite(f) else None
    if isinstance(x, Mapping):
        return {str(k): _convert(v, f"{where}.{k}") for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_convert(v, f"{where}[{i}]") for i, v in enumerate(x)]
    if isinstance(x, os.PathLike):
        return os.fspath(x)
    if hasattr(x, "__array__"):
        arr = np.asarray(x)
        if arr.dtype.kind not in "biuf":
            raise TypeError(f"{where}: cannot write an array of dtype {arr.dtype} as JSON")
        return _convert(arr.tolist(), where)
    raise TypeError(f"{where}: cannot write {type(x).__name__} as JSON")


def holds_declared_default(obj: Any, key: str) -> bool:
    """Whether field ``key`` of dataclass ``obj`` (dotted for nested ones: ``"ppo.lr"``)
    holds the default its class declares.

    A record written before a field existed lacks it; the run it describes is the same run
    when the field now holds its declared default (new options are added off by default), so
    resuming it is safe. A field without a default, or a key that names none, is False.
    """
    *path, name = key.split(".")
    for part in path:
        obj = getattr(obj, part, None)
    if not dataclasses.is_dataclass(obj) or isinstance(obj, type):
        return False
    field = {f.name: f for f in dataclasses.fields(obj)}.get(name)
    if field is None:
        return False
    if field.default is not dataclasses.MISSING:
        default = field.default
    elif field.default_factory is not dataclasses.MISSING:
        default = field.default_factory()
    else:
        return False
    return to_jsonable(getattr(obj, name)) == to_jsonable(default)


def write_json(path: str | os.PathLike, obj: Any) -> Path:
    """Atomically write ``obj`` (through :func:`to_jsonable`) as indented JSON plus a newline."""
    path = Path(path)
    text = json.dumps(to_jsonable(obj, name=f"{path}: value"), indent=2, allow_nan=False)
    return atomic_write(path, text + "\n")


def read_json(path: str | os.PathLike) -> Any:
    """The JSON document in ``path``; a damaged or truncated file raises ``ValueError`` naming
    the file (a missing one raises ``FileNotFoundError``)."""
    path = Path(path)
    text = _read_text(path)
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: damaged or truncated JSON ({e})") from e


def _line(record: Any, where: str) -> str:
    return json.dumps(to_jsonable(record, name=where), allow_nan=False) + "\n"


def write_jsonl(path: str | os.PathLike, records: Iterable[Any]) -> Path:
    """Atomically replace ``path`` with one compact JSON line per record."""
    path = Path(path)
    text = "".join(_line(r, f"{path}: record {i}") for i, r in enumerate(records))
    return atomic_write(path, text)


def append_jsonl(path: str | os.PathLike, records: Iterable[Any]) -> Path:
    """Append one JSON line per record to ``path`` (created if missing), then fsync.

    Every record is converted before anything is written, so bad input leaves the file as it
    was. A torn last line left by an interrupted append is cut off first, so the new records
    never run into it.
    """
    path = Path(path)
    lines = (_line(r, f"{path}: appended record {i}") for i, r in enumerate(records))
    text = "".join(lines).encode("utf-8")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+b") as f:
        end = f.seek(0, os.SEEK_END)
        if end:
            f.seek(end - 1)
            if f.read(1) != b"\n":
                f.seek(0)
                keep = f.read().rfind(b"\n") + 1
                f.truncate(keep)
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    return path


def read_jsonl(path: str | os.PathLike) -> list[Any]:
    """The records in a JSON-lines file, in order; blank lines are skipped.

    A last line with no newline that does not parse is a torn append and is dropped. Any other
    line that does not parse raises ``ValueError`` naming the file and the 1-based line.
    """
    path = Path(path)
    lines = path.read_bytes().split(b"\n")  # the last item is b"" iff the file ends in "\n"
    records = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line.decode("utf-8")))
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            if i == len(lines) - 1:
                break  # torn: an append cut short before its newline
            raise ValueError(f"{path}, line {i + 1}: damaged JSON record ({e})") from e
    return records


def _read_text(path: Path) -> str:
    try:
        return path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: damaged file, not UTF-8 text ({e})") from e
