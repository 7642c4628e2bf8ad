"""What the learner and the shield carry of the checker per env: the frames embedded once
each (:func:`embed`) and the checker's carry of fresh episodes (:func:`start_memory`), for a
checker of any kind (:class:`checker.protocol.CheckerProtocol`) or none.

Both the rollout (:mod:`agents.rollout`) and the shield's evaluation episodes
(:meth:`agents.shield.Shield.start`) start episodes here, so that they embed an episode's
first frame alike: reached by :data:`~checker.protocol.NO_ACTION`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from checker.protocol import NO_ACTION, CheckerProtocol


def embed(
    checker: CheckerProtocol | None, images: jax.Array, actions: jax.Array | None = None
) -> jax.Array:
    """The checker's per-frame embeddings (..., D) of ``images`` reached by ``actions`` (...)
    (None: episodes' first frames, :data:`~checker.protocol.NO_ACTION`); a zero placeholder
    (..., 1) without a checker."""
    if checker is None:
        return jnp.zeros(images.shape[:-3] + (1,), jnp.float32)
    if actions is None:
        actions = jnp.full(images.shape[:-3], NO_ACTION, jnp.int32)
    return checker.embed_states(images, actions)


def start_memory(checker: CheckerProtocol | None, emb: jax.Array, lang: jax.Array | None):
    """The checker's carry of fresh episodes whose first frames embed to ``emb``
    (:meth:`~checker.protocol.CheckerProtocol.stream_start`). Without a checker a (E, 1, 1)
    placeholder: orbax cannot checkpoint zero-size arrays."""
    if checker is None:
        return jnp.zeros(emb.shape[:1] + (1, 1), jnp.float32)
    return checker.stream_start(emb, lang)
