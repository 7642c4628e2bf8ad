"""A trained checker as one pytree (:class:`TrainedChecker`), and its save/load to a directory.

A checker directory holds ``params.msgpack`` (the Flax parameters, ``flax.serialization``)
and ``config.json`` (the :class:`~checker.model.CheckerConfig`, the label ``lookahead``, the
``env_id`` it was trained on, the decision ``threshold`` and the vocabulary and ``MAX_LEN``
it was trained with, and ``params_sha256``, the checksum of ``params.msgpack``). :func:`load`
refuses a directory made for another vocabulary or sentence length, since token ids would then
mean other words, and a parameter file whose checksum differs (truncated, bit-flipped, or
replaced without its ``config.json``), which would otherwise load as other numbers.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import jax.numpy as jnp
from flax import serialization, struct

from checker.model import Checker, CheckerConfig, init_params, params_shape
from jaxgrid import language
from jaxgrid.io import atomic_write, read_json, write_json
from jaxgrid.rundir import sha256_bytes

PARAMS_FILE = "params.msgpack"
CONFIG_FILE = "config.json"
FORMAT_VERSION = 1


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

    def embed_states(self, frames: jax.Array) -> jax.Array:
        return self.module.apply(self.params, frames, method=Checker.embed_states)

    def classify(self, state_emb: jax.Array, lang: jax.Array) -> jax.Array:
        return self.module.apply(self.params, state_emb, lang, method=Checker.classify)


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


def _vocab_meta() -> dict:
    return {"vocab": list(language.VOCAB), "max_len": language.MAX_LEN}


def check_vocab(meta: dict, where: str) -> None:
    """Raise ``ValueError`` if ``meta`` (with ``vocab``/``max_len``) is not this vocabulary."""
    vocab, max_len = meta.get("vocab"), meta.get("max_len")
    if vocab != list(language.VOCAB) or max_len != language.MAX_LEN:
        raise ValueError(
            f"{where} was made for another constraint vocabulary (vocab of "
            f"{len(vocab) if isinstance(vocab, list) else vocab!r} words, MAX_LEN {max_len}); "
            f"this jaxgrid.language has {language.vocab_size()} words and MAX_LEN "
            f"{language.MAX_LEN}, so its token ids would mean other words"
        )


def save(trained: TrainedChecker, directory: str | os.PathLike) -> str:
    """Write ``params.msgpack`` and ``config.json`` under ``directory`` (created if needed).

    Each file is written atomically, parameters first: a reader never sees half a file, and
    a crash between the two leaves a ``config.json`` whose checksum the new parameters fail.
    """
    directory = os.fspath(directory)
    data = serialization.to_bytes(jax.device_get(trained.params))
    atomic_write(os.path.join(directory, PARAMS_FILE), data)
    meta = {
        "format_version": FORMAT_VERSION,
        "params_sha256": sha256_bytes(data),
        "config": trained.config.to_dict(),
        "lookahead": trained.lookahead,
        "env_id": trained.env_id,
        "threshold": trained.threshold,
        **_vocab_meta(),
    }
    write_json(os.path.join(directory, CONFIG_FILE), meta)
    return directory


def params_sha256(directory: str | os.PathLike) -> str | None:
    """The checksum of the parameters saved in ``directory`` (from its ``config.json``);
    ``None`` for a directory saved before checksums were recorded. A report records it, so
    that a report and a checker can be matched."""
    return read_json(os.path.join(os.fspath(directory), CONFIG_FILE)).get("params_sha256")


def load(directory: str | os.PathLike) -> TrainedChecker:
    """Restore a :class:`TrainedChecker` written by :func:`save`, ready to use.

    Raises ``FileNotFoundError`` naming the missing path, ``ValueError`` naming the file for a
    checker made for another vocabulary or ``MAX_LEN``, or a damaged file (a parameter file
    that fails the checksum recorded in ``config.json``; a directory saved before checksums
    were recorded is loaded without that check).
    """
    directory = os.fspath(directory)
    if not os.path.isdir(directory):
        raise FileNotFoundError(f"checker directory not found: {directory}")
    cfg_path = os.path.join(directory, CONFIG_FILE)
    params_path = os.path.join(directory, PARAMS_FILE)
    for p in (cfg_path, params_path):
        if not os.path.isfile(p):
            raise FileNotFoundError(f"checker file not found: {p}")
    meta = read_json(cfg_path)
    check_vocab(meta, f"checker {directory}")
    config = CheckerConfig.from_dict(meta["config"])
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
    template = params_shape(config)
    params = serialization.from_state_dict(template, state)
    want = jax.tree.map(lambda s: (s.shape, s.dtype), template)
    got = jax.tree.map(lambda a: (a.shape, a.dtype), params)
    if jax.tree.structure(want) != jax.tree.structure(got) or want != got:
        raise ValueError(f"{params_path} does not hold parameters of the checker in {cfg_path}")
    params = jax.tree.map(jnp.asarray, params)
    return TrainedChecker(
        params=params,
        config=config,
        lookahead=int(meta["lookahead"]),
        env_id=str(meta["env_id"]),
        threshold=float(meta["threshold"]),
    )
