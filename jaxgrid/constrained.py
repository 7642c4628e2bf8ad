"""The one declared interface of a constrained environment, and its shared implementation.

Every environment whose episodes carry a constraint (the paper's scenarios, HazardRooms, any
level built with a constraint) derives from :class:`ConstrainedEnvironment`; code outside it
(adapters, learners, checkers) tests ``isinstance(env, ConstrainedEnvironment)`` and reads only
what it declares:

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

Any level gets a constraint through :func:`constrain` (``jaxgrid.make(id, constraint=...)``):
a :class:`ConstrainedLevel` wraps the level, keeps its step rules exactly (its own ``step``
runs on its own state; the monitor judges the transition), and with ``lava="cost"`` lets lava
cost instead of ending the episode (:func:`harmless_lava`, HazardRooms' rule). The sentences
it draws from (:class:`SentenceDraw`) are checked against what the level declares it holds
(:meth:`jaxgrid.environment.Environment.contents`) before anything compiles.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Iterable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import language
from jaxgrid import monitor as M
from jaxgrid.constants import LAVA
from jaxgrid.dynamics import get_cell
from jaxgrid.environment import Environment
from jaxgrid.language import PAD, VOCAB
from jaxgrid.sentences import LEVELS, PAPER, SentenceTable
from jaxgrid.types import State, TimeStep

__all__ = [
    "LAVA_RULES",
    "ConstrainedEnvironment",
    "ConstrainedExtras",
    "ConstrainedLevel",
    "DoorConstraint",
    "EpisodeConstraint",
    "LevelExtras",
    "SentenceDraw",
    "check_lava",
    "check_weights",
    "constrain",
    "draw_row",
    "harmless_lava",
    "language_table",
    "sentence_draw",
    "sentence_tokens",
]

#: ``lava=``: MiniGrid's lava, which ends the episode (the default), or lava that only costs
#: what the constraint says and is walked on like floor.
LAVA_RULES = ("lethal", "cost")


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

    def upgrade_extras(self, saved: dict, grid: np.ndarray) -> ConstrainedExtras | None:
        """``state.extras`` in today's layout from ``saved``, extras that earlier code
        checkpointed (arrays keyed by field name, as orbax restores a pytree, with leading
        batch axes that ``grid``, ``(..., W, H, 3)``, shares), or None when ``saved`` is no
        older layout that this environment knows. Raises ``ValueError`` naming what does
        not fit. The default knows none."""
        return None

    def with_sentences(
        self, sentences: tuple[str, ...], weights: tuple[float, ...] | None, lava: str | None
    ) -> ConstrainedEnvironment:
        """This environment drawing each episode's constraint from ``sentences`` (by
        ``weights``, uniformly when None), with the lava rule ``lava`` (None: its own).

        :func:`constrain` calls it for an environment that is constrained already. The default
        refuses with a ``ValueError``: such an environment builds its layouts around its own
        table (the paper's scenarios guarantee every episode a run without a violation).
        """
        raise ValueError(
            f"{type(self).__name__} draws its constraints from its own table "
            f"({self.language_table.name}), and its layouts are built around them; give a "
            "sentence to HazardRooms-v0 or to a MiniGrid level instead"
        )

    def with_table(
        self, table: SentenceTable, weights, lava: str | None, name: str
    ) -> ConstrainedEnvironment:
        """This environment's layouts drawing from the rows of ``table`` that they can hold
        (``constrain(..., constraints=table)``; ``name`` names it in errors). The default
        refuses with a ``ValueError``: such an environment draws from its own table, and takes
        given sentences only (:meth:`with_sentences`)."""
        raise ValueError(f"{name} draws from its own table; give it sentences")

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


def harmless_lava(before: State, after: State, terminated: jax.Array) -> jax.Array:
    """``terminated`` without the end that entering lava brings: lava that costs what the
    constraint says and is walked on like floor (HazardRooms', and ``lava="cost"``). A step's
    other ends (the goal, a level's own rule) stay."""
    moved = jnp.any(after.agent_pos != before.agent_pos)
    return terminated & ~(moved & (get_cell(after.grid, after.agent_pos)[0] == LAVA))


def check_lava(lava) -> None:
    """``ValueError`` naming ``lava`` unless it is one of :data:`LAVA_RULES`."""
    if not (isinstance(lava, str) and lava in LAVA_RULES):
        raise ValueError(f"lava must be one of {LAVA_RULES}, got {lava!r}")


def draw_row(u: jax.Array, cumulative: jax.Array) -> jax.Array:
    """int32 row drawn from a uniform ``u`` with the weights whose running sums are
    ``cumulative`` (1-D, last entry positive); rows of zero weight are never drawn."""
    row = jnp.sum(cumulative <= u * cumulative[-1])
    return jnp.minimum(row, cumulative.shape[0] - 1).astype(jnp.int32)


# --------------------------------------------------------------------------------------
# Constraints on any level
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SentenceDraw:
    """The sentences a constrained level's episodes say, one drawn per episode.

    ``sentences`` (normalised), their ``weights`` (summing to 1), ``type_ids`` and
    ``template_ids`` (a table's own, or an index of
    :data:`~jaxgrid.language.CONSTRAINT_TYPES` and -1 for a given sentence), and the
    ``table`` whose token layout the episodes observe. Build one with :func:`sentence_draw`.
    """

    sentences: tuple[str, ...]
    weights: tuple[float, ...]
    type_ids: tuple[int, ...]
    template_ids: tuple[int, ...]
    table: SentenceTable


@functools.lru_cache(maxsize=8192)
def _parse(sentence: str) -> language.Constraint:
    return language.parse(sentence)


def check_weights(weights, n: int) -> tuple[float, ...]:
    """``weights`` for ``n`` sentences, normalised to sum 1; ``ValueError`` for another length,
    a negative, non-finite or non-numeric entry, or all 0."""
    if isinstance(weights, (str, bytes)) or not isinstance(weights, Iterable):
        raise ValueError(f"weights must be a sequence of {n} numbers, got {weights!r}")
    weights = tuple(weights)
    if len(weights) != n:
        raise ValueError(f"weights has {len(weights)} entries for {n} constraints")
    for w in weights:
        ok = isinstance(w, (int, float, np.integer, np.floating)) and not isinstance(w, bool)
        if not ok or not math.isfinite(w) or w < 0:
            raise ValueError(f"weights must be finite numbers >= 0, got {w!r} in {weights}")
    if sum(weights) <= 0:
        raise ValueError(f"weights must not all be 0, got {weights}")
    total = float(sum(weights))
    return tuple(float(w) / total for w in weights)


@functools.cache
def _table_draw(table: SentenceTable, contents, where: str) -> SentenceDraw:
    rows = [r for r in table.rows if contents.allows(_parse(r.sentence))]
    if not rows:
        raise ValueError(
            f"{where} holds nothing a sentence of the {table.name} table names (it holds "
            f"{contents.describe()})"
        )
    # Each type the level can say equally often, then each of its rows.
    per_type = {t: sum(r.type_id == t for r in rows) for t in {r.type_id for r in rows}}
    return SentenceDraw(
        sentences=tuple(r.sentence for r in rows),
        weights=tuple(1.0 / (len(per_type) * per_type[r.type_id]) for r in rows),
        type_ids=tuple(r.type_id for r in rows),
        template_ids=tuple(r.template_id for r in rows),
        table=table,
    )


def sentence_draw(
    contents, where: str, *, constraint=None, constraints=None, weights=None
) -> SentenceDraw:
    """The :class:`SentenceDraw` of ``constraint`` (one sentence), or ``constraints``: several
    sentences (drawn by ``weights``, uniformly when None) or a
    :class:`~jaxgrid.sentences.SentenceTable` (its rows that name only what ``contents`` holds;
    each of their types equally often, then each row of a type).

    Raises ``ValueError`` before anything compiles: for neither or both of ``constraint`` and
    ``constraints``, ``weights`` of another length than the sentences, negative, not finite or
    all 0 (or with a table), a sentence the language refuses (naming the word), and a
    sentence naming a kind, or a colour of a kind, that ``contents`` (what ``where``, a
    level's name, holds: :class:`~jaxgrid.contents.Contents`) never holds, naming the word.
    """
    if (constraint is None) == (constraints is None):
        raise ValueError("give one of constraint= (a sentence) or constraints= (several)")
    if isinstance(constraints, SentenceTable):
        if weights is not None:
            raise ValueError(
                "weights= goes with constraints= sentences; a table's rows are drawn each type "
                "equally often"
            )
        return _table_draw(constraints, contents, where)
    if constraint is not None:
        sentences = (constraint,)
    elif isinstance(constraints, (str, bytes)) or not isinstance(constraints, Iterable):
        raise ValueError(
            f"constraints= takes a sequence of sentences or a sentence table, got "
            f"{constraints!r} (one sentence: constraint=)"
        )
    else:
        sentences = tuple(constraints)
    if not sentences:
        raise ValueError("constraints= needs at least one sentence")
    parsed = [_parse(s) for s in sentences]
    for c in parsed:
        contents.check(c, where)
    n = len(sentences)
    return SentenceDraw(
        sentences=tuple(c.sentence for c in parsed),
        weights=(1.0 / n,) * n if weights is None else check_weights(weights, n),
        type_ids=tuple(c.type_id for c in parsed),
        template_ids=(-1,) * n,
        table=LEVELS,
    )


@functools.cache
def _draw_arrays(draw: SentenceDraw) -> dict:
    parsed = [_parse(s) for s in draw.sentences]
    return {
        "tokens": draw.table.tokenize_batch(draw.sentences),
        "type_id": np.array(draw.type_ids, np.int32),
        "template_id": np.array(draw.template_ids, np.int32),
        "cumulative": np.cumsum(np.array(draw.weights, np.float32)),
        "spec": M.encode_batch(parsed),
        "max_radius": max(cl.radius for c in parsed for cl in c.clauses),
    }


@struct.dataclass
class LevelExtras(ConstrainedExtras):
    """``state.extras`` of a :class:`ConstrainedLevel`: the constraint and monitor, and the
    level's own extras (``level``), which its ``step`` reads and writes."""

    level: Any


_CONFIG = ("width", "height", "max_steps", "view_size", "see_through_walls")


class ConstrainedLevel(ConstrainedEnvironment, kw_only=True):
    """A level with a constraint per episode; build it with :func:`constrain` (the module
    docstring says what it keeps and adds).

    ``level`` is the wrapped level; the configuration fields repeat its own (change them on
    the level: ``make(id, max_steps=..., constraint=...)``). ``draw`` says which sentences
    episodes say; ``lava`` is one of :data:`LAVA_RULES`. A reset is the level's reset from
    the same key (the same layout seed for seed) with a constraint drawn from a key folded
    from it; the observation adds ``constraint`` and ``info`` the constraint's keys.
    """

    level: Environment
    draw: SentenceDraw = struct.field(pytree_node=False)
    lava: str = struct.field(pytree_node=False, default="lethal")

    def __post_init__(self):
        if not isinstance(self.level, Environment) or isinstance(
            self.level, ConstrainedEnvironment
        ):
            raise ValueError("ConstrainedLevel.level must be an unconstrained level")
        if not isinstance(self.draw, SentenceDraw):
            raise ValueError("ConstrainedLevel.draw must be a SentenceDraw (see constrain)")
        check_lava(self.lava)
        for name in _CONFIG:
            if getattr(self, name) != getattr(self.level, name):
                raise ValueError(
                    f"ConstrainedLevel.{name} is its level's ({getattr(self.level, name)!r}); "
                    f"set it on the level: make(id, {name}=..., constraint=...)"
                )
        super().__post_init__()

    @property
    def language_table(self) -> SentenceTable:
        return self.draw.table

    @property
    def num_actions(self) -> int:
        return self.level.num_actions

    def min_size(self):
        return self.level.min_size()

    def contents(self):
        return self.level.contents()

    def with_sentences(self, sentences, weights, lava):
        """The same level drawing from ``sentences`` instead (``lava`` None: this one's)."""
        return constrain(self.level, constraints=sentences, weights=weights, lava=lava or self.lava)

    def constraint_table(self) -> dict:
        """The draw's rows (see :class:`SentenceDraw`): ``tokens``, ``type_id``,
        ``template_id``, ``spec``, ``cumulative`` (running sums of the weights)."""
        return _draw_arrays(self.draw)

    # --- the level's state inside ---------------------------------------------------------
    @staticmethod
    def level_state(state: State) -> State:
        """The level's own state inside ``state`` (its extras in place of the constraint's)."""
        return state.replace(extras=state.extras.level)

    def with_constraint(self, level_state: State, key: jax.Array) -> State:
        """The constrained state of a level's ``level_state`` (a reset, or a converted MiniGrid
        env's), its constraint drawn from ``key`` and its monitor started on its grid."""
        table = self.constraint_table()
        if len(self.draw.sentences) == 1:
            row = jnp.int32(0)
        else:
            row = draw_row(jax.random.uniform(key), jnp.asarray(table["cumulative"]))
        constraint = EpisodeConstraint(
            tokens=jnp.asarray(table["tokens"])[row],
            type_id=jnp.asarray(table["type_id"])[row],
            template_id=jnp.asarray(table["template_id"])[row],
        )
        spec = jax.tree.map(lambda a: jnp.asarray(a)[row], table["spec"])
        monitor = M.start(spec, level_state.grid, table["max_radius"])
        extras = LevelExtras(constraint=constraint, monitor=monitor, level=level_state.extras)
        return level_state.replace(extras=extras)

    # --- Environment ------------------------------------------------------------------------
    def generate(self, key: jax.Array) -> State:
        # A key folded from the layout's, which the level spends whole: the same layouts.
        return self.with_constraint(self.level.generate(key), jax.random.fold_in(key, 0x5AFE))

    def observe(self, state: State) -> dict:
        obs = self.level.observe(self.level_state(state))
        return {**obs, "constraint": state.extras.constraint.tokens}

    def info(self, state: State) -> dict:
        return {**self.level.info(self.level_state(state)), **super().info(state)}

    def mission(self, state: State) -> jax.Array:
        return self.level.mission(self.level_state(state))

    def mission_text(self, state: State) -> str:
        return self.level.mission_text(self.level_state(state))

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """The level's own step on its own state, then the monitor on the transition (and with
        ``lava="cost"``, no end on entering lava)."""
        inner = self.level_state(state)
        new, ts = self.level.step(inner, action)
        if self.lava == "cost":
            terminated = harmless_lava(inner, new, ts.terminated)
            ts = ts.replace(terminated=terminated, discount=1.0 - terminated.astype(jnp.float32))
        new = new.replace(extras=state.extras.replace(level=new.extras))
        new, cost, violation = self.judge(state, new)
        info = {**ts.info, **self.step_info(new, violation, cost)}
        obs = {**ts.observation, "constraint": new.extras.constraint.tokens}
        return new, ts.replace(observation=obs, info=info)


def constrain(
    env: Environment, *, constraint=None, constraints=None, weights=None, lava=None, name=None
) -> ConstrainedEnvironment:
    """``env`` with a constraint per episode: ``constraint`` (one sentence) or ``constraints``
    (several, drawn by ``weights``; or a :class:`~jaxgrid.sentences.SentenceTable`, its rows
    that ``env`` can hold), and ``lava`` (:data:`LAVA_RULES`; None: lethal). ``name`` (the
    id) names the level in errors.

    A level becomes a :class:`ConstrainedLevel`; an environment constrained already draws from
    the sentences instead of its own (:meth:`ConstrainedEnvironment.with_sentences`). Every bad
    input raises ``ValueError`` here, before anything compiles (see :func:`sentence_draw`).
    """
    if lava is not None:
        check_lava(lava)
    where = name or type(env).__name__
    if isinstance(env, ConstrainedEnvironment):
        if isinstance(constraints, SentenceTable):
            return env.with_table(constraints, weights, lava, where)
        draw = sentence_draw(
            env.contents(), where, constraint=constraint, constraints=constraints, weights=weights
        )
        return env.with_sentences(draw.sentences, None if weights is None else draw.weights, lava)
    draw = sentence_draw(
        env.contents(), where, constraint=constraint, constraints=constraints, weights=weights
    )
    config = {k: getattr(env, k) for k in _CONFIG}
    return ConstrainedLevel(**config, level=env, draw=draw, lava=lava or "lethal")
