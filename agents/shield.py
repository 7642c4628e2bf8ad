"""Action shields: before each step, remove the actions a judge expects to violate the constraint.

For every env and every action, a copy of the environment is stepped (pure JAX, ``vmap`` over
the actions), giving the candidate next observation of each action. A judge scores each
candidate:

* ``checker``: the trained checker's violation probability of the candidate observation read
  after its carry of the episode (:meth:`checker.protocol.CheckerProtocol.candidate_logits`:
  for a window checker the window of the last ``window - 1`` frames and the candidate, for a
  memory checker its memory advanced by the candidate); an action is blocked where it
  exceeds ``threshold``. A checker of just-before labels (``lookahead`` 1) blocks a candidate
  that leads to a state from which a violation is expected next, keeping the agent out of
  the states the ``checker`` reward mode penalises; a memory checker of the step into each
  frame (``lookahead`` 0) blocks the candidate step that it expects to violate, the
  monitor's question.
* ``monitor``: the ground-truth monitor's violation flag of the candidate step (a perfect
  one-step judge, the reference the learned checker is measured against).

Every constraint event is the agent entering a cell, and only ``forward`` moves the agent, so
the monitor, a judge of the step itself, is asked about ``forward`` alone (:data:`MOVES`; the
other actions' risk is 0): seven times fewer candidates, and no false alarm can block a turn.
A checker is asked about its ``shield_actions``: a memory checker of the step into each
frame about :data:`MOVES`, a window checker or a just-before memory checker about every
action, since turning can lead to a state from which a violation is expected next.

The policy samples from its distribution restricted to the allowed actions (renormalised);
where every action is blocked, the least risky one stays allowed. PPO learns from that masked
distribution: the mask is stored with each transition and applied again in the loss
(:func:`mask_logits`).
"""

from __future__ import annotations

from typing import Any

import flax.struct as struct
import jax
import jax.numpy as jnp

from agents.checker_carry import embed, start_memory
from agents.evaluation import violation_of
from checker.protocol import MOVES, CheckerProtocol

JUDGES = ("checker", "monitor")
# A blocked action's logit: its probability underflows to 0 and its log-probability stays
# finite, so entropies and log-ratios never see inf - inf.
BLOCKED_LOGIT = -1e9


def mask_logits(logits: jax.Array, allowed: jax.Array) -> jax.Array:
    """(..., A) logits with the blocked actions (``allowed`` False) removed."""
    return jnp.where(allowed, logits, BLOCKED_LOGIT)


def blocked_mass(logits: jax.Array, allowed: jax.Array) -> jax.Array:
    """(...,) the unmasked policy's probability of the blocked actions."""
    return jnp.sum(jax.nn.softmax(logits) * ~allowed, axis=-1)


def allow_least_risky(risk: jax.Array, threshold: float) -> jax.Array:
    """bool (E, A): ``risk <= threshold``, or only the least risky action where none passes."""
    allowed = risk <= threshold
    fallback = jax.nn.one_hot(jnp.argmin(risk, axis=-1), risk.shape[-1], dtype=bool)
    return jnp.where(allowed.any(-1, keepdims=True), allowed, fallback)


class Shield(struct.PyTreeNode):
    """A judge of candidate actions for a batch of envs.

    ``allowed(states, frames, lang) -> (allowed bool (E, A), risk float32 (E, A))`` where
    ``states`` are the envs' (raw, batched) states, ``frames`` the checker's memory of each
    env's episode (:attr:`agents.rollout.EnvCarry.frames`) and ``lang`` the checker's
    sentence codes (E, G); the ``monitor`` judge reads neither. ``judged`` names the actions
    whose candidates are scored (None: all); the others are never blocked.
    """

    env: Any = struct.field(pytree_node=False)
    judge: str = struct.field(pytree_node=False)
    # A leaf, so that agents swept over it in one program can each have their own.
    threshold: float | jax.Array = 0.5
    checker: CheckerProtocol | None = None
    judged: tuple[int, ...] | None = struct.field(pytree_node=False, default=None)

    @property
    def actions(self) -> tuple[int, ...]:
        """The actions whose candidates are scored."""
        return tuple(range(self.env.num_actions)) if self.judged is None else self.judged

    def candidates(self, states):
        """Step every judged action from every state: ``(states, timesteps)`` with axes (E, J)
        (J = ``len(self.actions)``)."""
        actions = jnp.asarray(self.actions, jnp.int32)
        step_all = jax.vmap(self.env.step, in_axes=(None, 0))
        return jax.vmap(step_all, in_axes=(0, None))(states, actions)

    def risk(self, states, frames: jax.Array, lang: jax.Array) -> jax.Array:
        """float32 (E, A): each action's violation probability (checker) or flag (monitor);
        0 for an action not judged."""
        _, ts = self.candidates(states)
        if self.judge == "monitor":
            risk = violation_of(ts).astype(jnp.float32)
        else:
            images = ts.observation["image"]
            actions = jnp.broadcast_to(jnp.asarray(self.actions, jnp.int32), images.shape[:2])
            emb = embed(self.checker, images, actions)  # (E, J, D)
            risk = jax.nn.sigmoid(self.checker.candidate_logits(frames, emb, lang))
        if self.judged is None:
            return risk
        everyone = jnp.zeros(risk.shape[:-1] + (self.env.num_actions,), risk.dtype)
        return everyone.at[..., jnp.asarray(self.judged)].set(risk)

    def allowed(self, states, frames: jax.Array, lang: jax.Array):
        """``(allowed bool (E, A), risk (E, A))``: :func:`allow_least_risky` of :meth:`risk`."""
        risk = self.risk(states, frames, lang)
        return allow_least_risky(risk, self.threshold), risk

    # -- episodes played without the learner's carry (evaluation) ---------------------
    def start(self, obs: dict):
        """The judge's memory of fresh episodes whose first observations are ``obs``: the
        checker's carry (:func:`agents.checker_carry.start_memory`) and its codes of each
        sentence."""
        if self.judge == "monitor":
            return ()
        lang = self.checker.encode_language(obs["constraint"])
        return start_memory(self.checker, embed(self.checker, obs["image"]), lang), lang

    def observe(self, memory, obs: dict, actions: jax.Array):
        """The memory after the envs took ``actions`` (E,) and moved on to ``obs`` (same
        episodes)."""
        if self.judge == "monitor":
            return memory
        frames, lang = memory
        emb = embed(self.checker, obs["image"], actions)
        return self.checker.stream_step(frames, emb, lang)[1], lang

    def allowed_now(self, memory, states):
        """:meth:`allowed` from a :meth:`start`/:meth:`observe` memory."""
        if self.judge == "monitor":
            return self.allowed(states, None, None)
        return self.allowed(states, *memory)


def make_shield(env, judge: str, checker=None, threshold: float = 0.5) -> Shield:
    """A :class:`Shield` for ``env``; the ``checker`` judge needs a trained ``checker``.

    The monitor judges :data:`MOVES` only, a checker its ``shield_actions``.
    """
    if judge not in JUDGES:
        raise ValueError(f"shield judge must be one of {JUDGES}, got {judge!r}")
    if judge == "checker" and checker is None:
        raise ValueError("a checker shield needs a trained checker")
    if not 0 < threshold < 1:
        raise ValueError(f"shield threshold must be in (0, 1), got {threshold!r}")
    judged = MOVES if judge == "monitor" else checker.shield_actions
    return Shield(env=env, judge=judge, threshold=float(threshold),
                  checker=checker if judge == "checker" else None, judged=judged)  # fmt: skip
