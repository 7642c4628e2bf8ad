"""The one store of trained checkers: :func:`save` and :func:`load` of either kind.

A checker directory holds ``params.msgpack`` (the Flax parameters, ``flax.serialization``)
and ``config.json``, one record naming the ``kind`` (``"window"``, :mod:`checker.model`, or
``"memory"``, :mod:`checker.memory_model`; a record without one is a window checker's), what
that kind records of itself (its configuration, label timing, ``env_id``, decision
``threshold``: its ``record()``), the vocabulary and ``MAX_LEN`` its token ids were made with,
``params_sha256`` (the checksum of ``params.msgpack``) and ``format_version``. :func:`load`
refuses a directory made for another vocabulary or sentence length, since token ids would
then mean other words, and a parameter file whose checksum differs (truncated, bit-flipped,
or replaced without its ``config.json``), which would otherwise load as other numbers.

The checker commands share what they check of their outputs before any work:
:func:`fresh_checker_dir` (a checker's ``--out`` is new, empty, or an earlier checker's that
``--overwrite`` clears, so no report of other parameters survives beside new ones) and
:func:`check_writable_file` (a report's path can be written).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
from flax import serialization

from checker.memory_model import TrainedMemoryChecker
from checker.model import TrainedChecker
from jaxgrid import language
from jaxgrid.io import atomic_write, read_json, write_json
from jaxgrid.rundir import LOCK_FILE, sha256_bytes, writing

PARAMS_FILE = "params.msgpack"
CONFIG_FILE = "config.json"
# 1: a window checker's record has no "kind"; 2: every record names its kind.
FORMAT_VERSION = 2
# What the checker commands write into a checker directory: all that --overwrite removes.
CHECKER_FILES = (PARAMS_FILE, CONFIG_FILE, "metrics.json", "report.json")
#: The trained checker of each kind, by the name its record gives.
KINDS = {cls.kind: cls for cls in (TrainedChecker, TrainedMemoryChecker)}


def save(trained, directory: str | os.PathLike) -> str:
    """Write ``trained`` (a checker of any kind of :data:`KINDS`) as ``params.msgpack`` and
    ``config.json`` under ``directory`` (created if needed); :func:`load` reads it back."""
    lang = trained.language
    meta = {"kind": trained.kind, **trained.record(), "vocab": list(lang.VOCAB),
            "max_len": lang.MAX_LEN}  # fmt: skip
    return write_params(trained.params, directory, meta)


def load(directory: str | os.PathLike):
    """Restore the checker saved in ``directory`` by :func:`save`, of the kind its record
    names, ready to use.

    Raises ``FileNotFoundError`` naming the missing path, ``ValueError`` naming the file for a
    checker made for another vocabulary or ``MAX_LEN``, of an unknown kind or a newer format,
    or a damaged file (a parameter file that fails the checksum recorded in ``config.json``;
    a directory saved before checksums were recorded is loaded without that check).
    """
    meta = read_meta(directory)
    cls = KINDS[_kind(meta, directory)]
    check_vocab(meta, f"checker {os.fspath(directory)}", cls.language)
    return cls.from_record(meta, lambda template: read_params(directory, template, meta))


def checker_kind(directory: str | os.PathLike) -> str:
    """What the checker saved in ``directory`` remembers, ``"window"`` or ``"memory"``, from
    its ``config.json`` alone (nothing is loaded or compiled), so that a command can refuse a
    checker of the wrong kind among its flags; errors as :func:`load`'s."""
    return _kind(read_meta(directory), directory)


def _kind(meta: dict, directory) -> str:
    where = os.path.join(os.fspath(directory), CONFIG_FILE)
    version = meta.get("format_version", 1)
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise ValueError(f"{where}: format_version {version!r}, newer than this code reads "
                         f"({FORMAT_VERSION})")  # fmt: skip
    kind = meta.get("kind", "window")
    if kind not in KINDS:
        raise ValueError(f"{where}: unknown checker kind {kind!r}")
    return kind


def check_vocab(meta: dict, where: str, lang=language) -> None:
    """Raise ``ValueError`` if ``meta`` (with ``vocab``/``max_len``) is not the vocabulary of
    ``lang`` (a language module: :mod:`jaxgrid.language` or :mod:`jaxgrid.hazard_language`)."""
    vocab, max_len = meta.get("vocab"), meta.get("max_len")
    if not isinstance(vocab, list):
        raise ValueError(f"{where}: its {CONFIG_FILE} records no constraint vocabulary (not a "
                         "checker's, or damaged), so its token ids cannot be checked")  # fmt: skip
    if vocab != list(lang.VOCAB) or max_len != lang.MAX_LEN:
        raise ValueError(
            f"{where} was made for another constraint vocabulary ({len(vocab)} words, MAX_LEN "
            f"{max_len}); "
            f"this {lang.__name__} has {lang.vocab_size()} words and MAX_LEN "
            f"{lang.MAX_LEN}, so its token ids would mean other words"
        )


def write_params(params, directory: str | os.PathLike, meta: dict) -> str:
    """Write ``params`` to ``params.msgpack`` and ``meta`` with its checksum to
    ``config.json``, each atomically, parameters first: a reader never sees half a file, and
    a crash between the two leaves a ``config.json`` whose checksum the new parameters fail.
    Ctrl-C (:func:`jaxgrid.rundir.exit_now`) waits for both."""
    directory = os.fspath(directory)
    data = serialization.to_bytes(jax.device_get(params))
    meta = {"format_version": FORMAT_VERSION, "params_sha256": sha256_bytes(data), **meta}
    with writing():
        atomic_write(os.path.join(directory, PARAMS_FILE), data)
        write_json(os.path.join(directory, CONFIG_FILE), meta)
    return directory


def read_meta(directory: str | os.PathLike) -> dict:
    """A checker directory's ``config.json``; ``FileNotFoundError`` naming what is missing."""
    directory = os.fspath(directory)
    if not os.path.isdir(directory):
        raise FileNotFoundError(f"checker directory not found: {directory}")
    for name in (CONFIG_FILE, PARAMS_FILE):
        p = os.path.join(directory, name)
        if not os.path.isfile(p):
            raise FileNotFoundError(f"checker file not found: {p}")
    return read_json(os.path.join(directory, CONFIG_FILE))


def read_params(directory: str | os.PathLike, template, meta: dict):
    """The parameters saved in ``directory``, checked against ``meta``'s checksum and the
    shapes of ``template``; ``ValueError`` naming the file where they are damaged."""
    directory = os.fspath(directory)
    cfg_path = os.path.join(directory, CONFIG_FILE)
    params_path = os.path.join(directory, PARAMS_FILE)
    with open(params_path, "rb") as f:
        data = f.read()
    recorded = meta.get("params_sha256")
    if recorded is not None and sha256_bytes(data) != recorded:
        raise ValueError(
            f"{params_path}: damaged parameter file (truncated or changed: its sha256 differs "
            f"from the one in {cfg_path}); retrain the checker (`python -m checker --out "
            f"{directory} --overwrite`, or delete {directory} and rerun the experiment)"
        )
    try:
        state = serialization.msgpack_restore(data)
    except Exception as e:  # msgpack's errors share no base class with a clear message
        raise ValueError(f"{params_path}: damaged parameter file ({type(e).__name__}: {e})") from e
    params = serialization.from_state_dict(template, state)
    want = jax.tree.map(lambda s: (s.shape, s.dtype), template)
    got = jax.tree.map(lambda a: (a.shape, a.dtype), params)
    if jax.tree.structure(want) != jax.tree.structure(got) or want != got:
        raise ValueError(f"{params_path} does not hold parameters of the checker in {cfg_path}")
    return jax.tree.map(jnp.asarray, params)


def params_sha256(directory: str | os.PathLike) -> str | None:
    """The checksum of the parameters saved in ``directory`` (from its ``config.json``);
    ``None`` for a directory saved before checksums were recorded. A report records it, so
    that a report and a checker can be matched."""
    return read_json(os.path.join(os.fspath(directory), CONFIG_FILE)).get("params_sha256")


def fresh_checker_dir(out: str | os.PathLike, overwrite: bool) -> None:
    """Make the checker directory ``out`` (created and locked by the caller) empty, so that no
    file of an earlier checker (a report of other parameters) survives beside a new one.

    A non-empty ``out`` raises ``ValueError`` unless ``overwrite``; with it, the files of
    :data:`CHECKER_FILES` (and temporaries of an interrupted write) are removed, and a
    directory holding anything else is refused: it is not a checker directory.
    """
    out = os.fspath(out)
    entries = sorted(e for e in os.listdir(out) if e != LOCK_FILE)
    if not entries:
        return
    if not overwrite:
        raise ValueError(f"--out {out} is not empty ({', '.join(entries[:5])}); pick a new "
                         "directory, or pass --overwrite to replace the checker there")  # fmt: skip
    foreign = [e for e in entries if e not in CHECKER_FILES and not e.endswith(".tmp")]
    if foreign:
        raise ValueError(f"--out {out} holds files no checker command writes "
                         f"({', '.join(foreign[:5])}); --overwrite clears only a checker "
                         "directory: pick a new --out")  # fmt: skip
    for e in entries:
        os.remove(os.path.join(out, e))
    print(f"--overwrite: removed {', '.join(entries)} from {out}", file=sys.stderr)


def check_writable_file(path: str | os.PathLike, name: str = "") -> None:
    """``ValueError`` (its message starting with ``name``, e.g. ``Config.out``, which the
    command line shows as the flag) unless a file can be written at ``path``: a file there is
    replaced, the directories missing above it are created when it is written. Creates
    nothing. A command checks its output file so before its work, whose results a bad path
    would otherwise lose at the end."""
    target, what = Path(os.path.abspath(path)), f"{name} {path}".strip()
    if target.is_dir():
        raise ValueError(f"{what} is a directory, not a file")
    above = target.parent
    while not above.exists():
        above = above.parent
    if not above.is_dir():
        raise ValueError(f"{what}: {above} is a file, not a directory")
    if not os.access(above, os.W_OK | os.X_OK):
        raise ValueError(f"{what}: not writable (no permission to write in {above})")
