"""The one declared interface of a constrained environment, and its shared implementation.

Every environment whose episodes carry a constraint (the paper's scenarios, HazardRooms)
derives from :class:`ConstrainedEnvironment`; code outside it (adapters, learners, checkers)
tests ``isinstance(env, ConstrainedEnvironment)`` and reads only what it declares:

* :attr:`~ConstrainedEnvironment.language_table`: the :class:`~jaxgrid.sentences.SentenceTable`
  of ``observation["constraint"]`` (the token layout its models read);
* :meth:`~ConstrainedEnvironment.constraint_table`: numeric arrays of the rows its episodes
  draw from (``tokens`` ``(K, max_len)``, and ``spec``, each row's monitor encoding), and
  :attr:`~ConstrainedEnvironment.every_sentence_in_table`: whether every sentence an episode
  can say is one of those rows;
* the state: ``state.extras`` is a :class:`ConstrainedExtras`, the episode's
  :class:`EpisodeConstraint` and its :class:`~jaxgrid.monitor.Monitor`, the one judge of
  ``violation`` and ``cost`` (:meth:`~ConstrainedEnvironment.judge`);
* the keys it observes and reports: :attr:`~ConstrainedEnvironment.OBSERVATION_KEYS` and
  :attr:`~ConstrainedEnvironment.INFO_KEYS`, at reset and at every step.

:func:`language_table` and :func:`sentence_tokens` answer for any environment, with the paper's
token layout for one without a constraint (models built for it keep their sizes).
"""

from __future__ import annotations

from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import monitor as M
from jaxgrid.environment import Environment
from jaxgrid.language import PAD, VOCAB
from jaxgrid.sentences import PAPER, SentenceTable
from jaxgrid.types import State

__all__ = [
    "ConstrainedEnvironment",
    "ConstrainedExtras",
    "DoorConstraint",
    "EpisodeConstraint",
    "language_table",
    "sentence_tokens",
]


@struct.dataclass
class EpisodeConstraint:
    """The episode's constraint as the agent reads it and metrics group it."""

    tokens: jax.Array  # int32 (max_len,) token ids of the env's language table
    type_id: jax.Array  # int32 info["constraint_type"]: the table's type of the sentence
    template_id: jax.Array  # int32 template of the table's row (-1: a given sentence)


@struct.dataclass
class DoorConstraint(EpisodeConstraint):
    """A constraint forbidding one door colour (the paper's table), which planners read: the
    oracle plans around ``door_colour``, so that a policy may plan with another colour."""

    door_colour: jax.Array  # int32 MiniGrid colour index of the forbidden door


@struct.dataclass
class ConstrainedExtras:
    """``state.extras`` of a constrained environment; subclasses add their own fields."""

    constraint: EpisodeConstraint
    monitor: M.Monitor


class ConstrainedEnvironment(Environment):
    """Base of every environment with a constraint per episode (see the module docstring).

    Subclasses set :attr:`language_table`, implement :meth:`constraint_table` and
    :meth:`generate` (whose state's extras are a :class:`ConstrainedExtras`), and in ``step``
    call :meth:`judge` between the transition and anything that moves the agent on.
    """

    #: Observation keys: MiniGrid's, and the constraint's token ids.
    OBSERVATION_KEYS: ClassVar[tuple[str, ...]] = ("image", "direction", "constraint")
    #: Info keys of every step, reset included.
    INFO_KEYS: ClassVar[tuple[str, ...]] = ("violation", "cost", "constraint_type", "template_id")
    #: The table of ``observation["constraint"]``.
    language_table: ClassVar[SentenceTable]

    def constraint_table(self) -> dict:
        """Numeric arrays of the rows episodes draw from, row k = sentence k: at least
        ``tokens`` int32 ``(K, language_table.max_len)`` and ``spec``, a
        :class:`~jaxgrid.monitor.ClauseSpec` of ``(K, NUM_CLAUSES)`` arrays."""
        raise NotImplementedError

    @property
    def every_sentence_in_table(self) -> bool:
        """Whether :meth:`constraint_table` lists every sentence an episode can say."""
        return True

    def observe(self, state: State) -> dict:
        obs = super().observe(state)
        obs["constraint"] = state.extras.constraint.tokens
        return obs

    def info(self, state: State) -> dict:
        return self.step_info(state, jnp.zeros((), bool), jnp.zeros((), jnp.float32))

    def step_info(self, state: State, violation: jax.Array, cost: jax.Array) -> dict:
        """The :attr:`INFO_KEYS` of a step that ended in ``state``."""
        c = state.extras.constraint
        return {
            "violation": violation,
            "cost": cost,
            "constraint_type": c.type_id,
            "template_id": c.template_id,
        }

    def judge(self, before: State, after: State) -> tuple[State, jax.Array, jax.Array]:
        """``(after, cost, violation)``: the monitor advanced by the step ``before -> after``
        (the transition's result, before anything moves the agent on) and kept in ``after``."""
        monitor, cost, violation = M.update(
            before.extras.monitor, before.agent_pos, after.agent_pos, before.carrying,
            after.carrying,
        )  # fmt: skip
        return after.replace(extras=after.extras.replace(monitor=monitor)), cost, violation


def language_table(env) -> SentenceTable:
    """The table whose token ids ``env`` observes; the paper's for an env without one, so
    that a model built for it keeps the paper's embedding size."""
    return env.language_table if isinstance(env, ConstrainedEnvironment) else PAPER


def sentence_tokens(env) -> np.ndarray:
    """int32 ``(K, max_len)`` token ids of every sentence of ``env``'s constraint table (the
    rows it draws from), or one pad row for an env without one, so that code indexing the
    table works unchanged."""
    if not isinstance(env, ConstrainedEnvironment):
        return np.full((1, PAPER.max_len), VOCAB.index(PAD), np.int32)
    return np.asarray(env.constraint_table()["tokens"], np.int32)
