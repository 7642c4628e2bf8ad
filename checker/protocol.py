"""What every trained checker offers, whatever its kind: the one interface that PPO's rollout
and reward, the shield and evaluation call, so that none of them asks which kind it holds.

A kind is what a checker remembers of the episode: ``"window"`` (:mod:`checker.model`, the
paper's: the last ``n`` frames and the sentence) or ``"memory"`` (:mod:`checker.memory_model`:
a GRU state over every frame of the episode, for constraints that count). Both are trained
by :mod:`checker.train`, saved and loaded by :mod:`checker.store`.

On device a checker runs per env as a stream: :meth:`~CheckerProtocol.stream_start` gives the
carry of fresh episodes from their first frames, :meth:`~CheckerProtocol.stream_step` the
logit of the next frame and the carry with it in, :meth:`~CheckerProtocol.candidate_logits`
the logits of several candidate next frames from one carry (what a shield asks), frames
embedded once by :meth:`~CheckerProtocol.embed_states` (with the actions that led into them,
:data:`NO_ACTION` into an episode's first) and sentences by
:meth:`~CheckerProtocol.encode_language`.

Label timing is ``lookahead``: a frame is labelled by a violation within the next
``lookahead`` steps (1: the step out of it, "just before", the paper's), or with 0 by the step
into it. Memory checkers saved before the name was shared record it as ``label``, ``"next"``
or ``"into"`` (:data:`LABEL_LOOKAHEADS`), which is read as the lookahead it means.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any, ClassVar, Protocol

import jax

from jaxgrid.constants import FORWARD

#: The checker kinds, by the name a saved checker's record gives.
KINDS = ("window", "memory")
#: The "action" into an episode's first frame (one past MiniGrid's seven actions).
NO_ACTION = 7
#: The actions that can move the agent into another cell, the only ones that can violate.
MOVES = (FORWARD,)
#: The memory checker's former names of its label timings, and the lookahead each one is.
LABEL_LOOKAHEADS = {"next": 1, "into": 0}


class CheckerProtocol(Protocol):
    """A trained checker: parameters (its only pytree leaf) and static settings, pure and
    jittable methods; it can be passed through ``jax.jit`` as an argument.

    ``reads`` says what it is trained on: ``"window"`` (datasets of windows of the last
    frames with their sentence, :class:`checker.data.CheckerDataset`) or ``"stream"`` (whole
    streams of frames, episode starts, sentences and actions,
    :func:`checker.data.collect_streams`). ``shield_actions`` are the actions whose candidate
    next frames a shield must score (``None``: all of them): a checker of the step into each
    frame can only alarm on a step that enters a cell (:data:`MOVES`). ``language`` is the
    module of the sentences its token ids spell (:mod:`jaxgrid.language` or its hazard
    extension), ``config`` its sizes (``view_size``, ``vocab_size`` and ``max_len`` among
    them).
    """

    kind: ClassVar[str]
    reads: ClassVar[str]
    language: ClassVar[ModuleType]
    params: Any
    config: Any
    lookahead: int
    env_id: str
    threshold: float

    @property
    def shield_actions(self) -> tuple[int, ...] | None: ...

    def encode_language(self, tokens: jax.Array) -> jax.Array:
        """int32 token ids ``(..., L)`` -> sentence codes ``(..., G)``."""
        ...

    def embed_states(self, frames: jax.Array, actions: jax.Array | None = None) -> jax.Array:
        """uint8 frames ``(..., V, V, 3)`` reached by ``actions`` ``(...)`` -> codes
        ``(..., D)``; a kind that reads no actions ignores them."""
        ...

    def stream_start(self, emb: jax.Array, lang: jax.Array) -> Any:
        """The carry of fresh episodes whose first frames embed to ``emb`` ``(E, D)``, read
        with sentence codes ``lang`` ``(E, G)``."""
        ...

    def stream_step(self, carry: Any, emb: jax.Array, lang: jax.Array) -> tuple[jax.Array, Any]:
        """``(logit (E,), carry)``: the violation logit of the next frame, embedded as ``emb``
        ``(E, D)``, and the carry with that frame in it."""
        ...

    def candidate_logits(self, carry: Any, emb: jax.Array, lang: jax.Array) -> jax.Array:
        """Logits ``(E, A)`` of :meth:`stream_step` for each of ``A`` candidate next frames
        embedded as ``emb`` ``(E, A, D)``, from one carry per env."""
        ...

    def record(self) -> dict:
        """What :func:`checker.store.save` records of it beside its parameters (JSON)."""
        ...
