"""A trained checker as one pytree (:class:`TrainedChecker`), and its save/load to a directory.

A checker directory holds ``params.msgpack`` (the Flax parameters, ``flax.serialization``)
and ``config.json`` (the :class:`~checker.model.CheckerConfig`, the label ``lookahead``, the
``env_id`` it was trained on, the decision ``threshold`` and the vocabulary and ``MAX_LEN``
it was trained with, and ``params_sha256``, the checksum of ``params.msgpack``). :func:`load`
refuses a directory made for another vocabulary or sentence length, since token ids would then
mean other words, and a parameter file whose checksum differs (truncated, bit-flipped, or
replaced without its ``config.json``), which would otherwise load as other numbers.

The checker commands share what they check of their outputs before any work:
:func:`fresh_checker_dir` (a checker's ``--out`` is new, empty, or an earlier checker's that
``--overwrite`` clears, so no report of other parameters survives beside new ones) and
:func:`check_writable_file` (a report's path can be written).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
from flax import serialization, struct

from checker.model import Checker, CheckerConfig, candidate_logits, init_params, params_shape
from jaxgrid.io import atomic_write, read_json, write_json
from jaxgrid.rundir import LOCK_FILE, sha256_bytes, writing
from jaxgrid.sentences import PAPER, SentenceTable

PARAMS_FILE = "params.msgpack"
CONFIG_FILE = "config.json"
FORMAT_VERSION = 1
# What the checker commands write into a checker directory: all that --overwrite removes.
CHECKER_FILES = (PARAMS_FILE, CONFIG_FILE, "metrics.json", "report.json")


class TrainedChecker(struct.PyTreeNode):
    """Parameters (the only pytree leaf) + static configuration of a trained checker.

    Every method is a thin wrapper over ``Checker(config).apply(params, ...)``, pure and
    jittable; a ``TrainedChecker`` can be passed through ``jax.jit`` as an argument.
    """

    params: Any
    config: CheckerConfig = struct.field(pytree_node=False)
    lookahead: int = struct.field(pytree_node=False, default=1)
    env_id: str = struct.field(pytree_node=False, default="")
    threshold: float = struct.field(pytree_node=False, default=0.5)
    kind = "window"  # what it remembers: the last frames (checker.memory's: "memory")

    @property
    def module(self) -> Checker:
        return Checker(self.config)

    def logits(self, windows: jax.Array, tokens: jax.Array) -> jax.Array:
        """uint8 ``(B, n, V, V, 3)``, int32 ``(B, L)`` -> float32 logits ``(B,)``."""
        return self.module.apply(self.params, windows, tokens)

    def probs(self, windows: jax.Array, tokens: jax.Array) -> jax.Array:
        """Violation probabilities ``(B,)`` (sigmoid of :meth:`logits`)."""
        return jax.nn.sigmoid(self.logits(windows, tokens))

    def encode_language(self, tokens: jax.Array) -> jax.Array:
        return self.module.apply(self.params, tokens, method=Checker.encode_language)

    def embed_states(self, frames: jax.Array, actions: jax.Array | None = None) -> jax.Array:
        """Frame embeddings; ``actions`` (the memory checker's interface) is unused: the
        window checker reads frames only."""
        del actions
        return self.module.apply(self.params, frames, method=Checker.embed_states)

    def classify(self, state_emb: jax.Array, lang: jax.Array) -> jax.Array:
        return self.module.apply(self.params, state_emb, lang, method=Checker.classify)

    # -- streams: what a learner carries per env (shared with the memory checker) --------
    def stream_start(self, emb: jax.Array, lang: jax.Array) -> jax.Array:
        """The memory of episodes whose first frames embed to ``emb`` (E, D): the embeddings
        of the last ``window - 1`` frames (E, n - 1, D), blank frames before the first.
        ``lang`` is unused (the window is read with the sentence when it is scored)."""
        del lang
        v = self.config.view_size
        blank = self.embed_states(jnp.zeros((1, v, v, 3), jnp.uint8))
        n = self.config.window
        older = jnp.broadcast_to(blank[:, None], (emb.shape[0], max(n - 2, 0), emb.shape[-1]))
        return jnp.concatenate([older, emb[:, None]], axis=1)[:, max(2 - n, 0) :]

    def stream_step(self, memory: jax.Array, emb: jax.Array, lang: jax.Array):
        """``(logit (E,), memory)``: the violation logit of the window ending at the frame
        embedded as ``emb``, and the memory with that frame in it."""
        window = jnp.concatenate([memory, emb[:, None]], axis=1)
        return self.classify(window, lang), window[:, 1:]

    def candidate_logits(self, memory: jax.Array, emb: jax.Array, lang: jax.Array):
        """Logits ``(E, A)`` of :meth:`stream_step` for each of ``A`` candidate frames
        embedded as ``emb`` (E, A, D), from one memory per env (what a shield asks)."""
        return candidate_logits(self.params, self.config, memory, emb, lang)


def new_checker(
    config: CheckerConfig,
    key: jax.Array,
    *,
    lookahead: int = 1,
    env_id: str = "",
    threshold: float = 0.5,
) -> TrainedChecker:
    """An untrained (freshly initialised) checker."""
    return TrainedChecker(
        params=init_params(config, key),
        config=config,
        lookahead=int(lookahead),
        env_id=str(env_id),
        threshold=float(threshold),
    )


def _vocab_meta(table: SentenceTable = PAPER) -> dict:
    return {"vocab": list(table.vocab), "max_len": table.max_len}


def check_vocab(meta: dict, where: str, table: SentenceTable = PAPER) -> None:
    """Raise ``ValueError`` if ``meta`` (with ``vocab``/``max_len``) is not the token layout of
    ``table`` (a :class:`jaxgrid.sentences.SentenceTable`: the paper's, HazardRooms')."""
    vocab, max_len = meta.get("vocab"), meta.get("max_len")
    if not isinstance(vocab, list):
        raise ValueError(f"{where}: its {CONFIG_FILE} records no constraint vocabulary (not a "
                         "checker's, or damaged), so its token ids cannot be checked")  # fmt: skip
    if vocab != list(table.vocab) or max_len != table.max_len:
        raise ValueError(
            f"{where} was made for another constraint vocabulary ({len(vocab)} words, MAX_LEN "
            f"{max_len}); "
            f"the {table.name} sentence table has {table.vocab_size} words and MAX_LEN "
            f"{table.max_len}, so its token ids would mean other words"
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


def save(trained: TrainedChecker, directory: str | os.PathLike) -> str:
    """Write ``params.msgpack`` and ``config.json`` under ``directory`` (created if needed)."""
    meta = {
        "config": trained.config.to_dict(),
        "lookahead": trained.lookahead,
        "env_id": trained.env_id,
        "threshold": trained.threshold,
        **_vocab_meta(),
    }
    return write_params(trained.params, directory, meta)


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


def checker_kind(directory: str | os.PathLike) -> str:
    """What the checker saved in ``directory`` remembers, ``"window"`` or ``"memory"``, from
    its ``config.json`` alone (nothing is loaded or compiled), so that a command can refuse a
    checker of the wrong kind among its flags; errors as :func:`read_meta`'s."""
    kind = read_meta(directory).get("kind", "window")
    if kind not in ("window", "memory"):
        raise ValueError(f"{os.path.join(os.fspath(directory), CONFIG_FILE)}: unknown checker "
                         f"kind {kind!r}")  # fmt: skip
    return kind


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


def load(directory: str | os.PathLike):
    """Restore a checker written by :func:`save` (a :class:`TrainedChecker`) or by
    :func:`checker.memory.save` (a :class:`~checker.memory.TrainedMemoryChecker`), ready to
    use.

    Raises ``FileNotFoundError`` naming the missing path, ``ValueError`` naming the file for a
    checker made for another vocabulary or ``MAX_LEN``, or a damaged file (a parameter file
    that fails the checksum recorded in ``config.json``; a directory saved before checksums
    were recorded is loaded without that check).
    """
    meta = read_meta(directory)
    if meta.get("kind") == "memory":
        from checker import memory

        return memory.load(directory, meta)
    check_vocab(meta, f"checker {os.fspath(directory)}")
    config = CheckerConfig.from_dict(meta["config"])
    params = read_params(directory, params_shape(config), meta)
    return TrainedChecker(
        params=params,
        config=config,
        lookahead=int(meta["lookahead"]),
        env_id=str(meta["env_id"]),
        threshold=float(meta["threshold"]),
    )
