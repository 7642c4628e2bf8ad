"""The paper's three scenarios, each episode with a fresh random constraint.

* ``TwoRooms-v0``: two rooms split by a vertical wall holding two closed doors of distinct
  colours; agent and goal start in different rooms.
* ``TwoRoomsLava-v0``: TwoRooms plus one lava cell in the agent's room, never in front of a door.
  If the constraint mentions lava, lava is lethal (MiniGrid) and entering it is a violation;
  otherwise lava teleports the agent to a free cell next to the goal (no termination, no
  violation), so avoiding it has a cost and the constraint matters.
* ``ThreeRoomsKey-v0``: room 1 holds agent and key; wall 1 has a locked door of the key's
  colour; wall 2 has a closed door and a gap in its bottom row (the longer route); the goal is
  the top-right interior cell. Constraints never name the locked door.

Door colours are distinct and drawn from the five non-green colours; the agent's direction is
random. Every episode can be solved without a violation: a constraint forbids one door colour
(and maybe lava) and there is always another way. Constraints are rows of the paper's sentence
table (:data:`jaxgrid.sentences.PAPER`), all those of the split or only those given
(``jaxgrid.make(id, constraint=...)`` or ``constraints=``); the monitor
(:mod:`jaxgrid.monitor`) in the state judges them, as for every constrained environment: a
violation is the agent *entering* a forbidden cell (a door of the forbidden colour, or lava
when lava is forbidden). Each step reports ``info["violation"]``, ``info["cost"]``,
``info["constraint_type"]`` (paper type 1-5) and ``info["template_id"]``.

Any other sentence of the language (a budget, a sequence, a distance, or paper sentences with
``weights=`` or ``lava=``) constrains the scenario's layouts as every MiniGrid level is
constrained (:func:`jaxgrid.constrained.constrain` of :class:`ScenarioLayouts`, the same
layouts seed for seed): MiniGrid's lava (or ``lava="cost"``), tokens of the levels' table,
and no promise that an episode can be solved without a violation.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import grid as G
from jaxgrid import language, sentences
from jaxgrid import monitor as M
from jaxgrid.constants import (
    CLOSED,
    COLOR_TO_IDX,
    DOOR,
    GOAL_CELL,
    KEY,
    LAVA,
    LAVA_CELL,
    LOCKED,
    WALL_CELL,
)
from jaxgrid.constrained import (
    ConstrainedEnvironment,
    ConstrainedExtras,
    DoorConstraint,
    constrain,
)
from jaxgrid.contents import Contents
from jaxgrid.dynamics import get_cell, transition
from jaxgrid.environment import Environment, check_action
from jaxgrid.paraphrases import SPLITS
from jaxgrid.sentences import PAPER
from jaxgrid.types import State, TimeStep

#: Door colours, MiniGrid indices: the five non-green colours the tables name (never the goal's).
DOOR_COLOURS = np.array([COLOR_TO_IDX[c] for c in sentences.DOOR_COLOURS], np.int32)


@struct.dataclass
class ScenarioExtras(ConstrainedExtras):
    """The constraint (``type_id`` its paper type, ``template_id`` a
    :data:`jaxgrid.sentences.TEMPLATES` index) and monitor, the goal, and the teleport cell."""

    goal_pos: jax.Array  # int32 (2,)
    teleport_pos: jax.Array  # int32 (2,): where allowed lava sends the agent


@functools.cache
def _constraint_table(split: str, has_lava: bool, given: tuple[str, ...] | None = None) -> dict:
    """The split's (template, colour) rows with their monitor ``spec``; with ``given``
    (sentences as :data:`PAPER` spells them), only the rows that say one of them."""
    table = sentences.combination_table(split, include_lava=has_lava)
    combos = sentences.split_combinations(split, include_lava=has_lava)
    if given is not None:
        keep = np.array([sentences.render(t, c) in given for t, c in combos])
        table = {k: v[keep] for k, v in table.items()}
        combos = [c for c, k in zip(combos, keep, strict=True) if k]
    table["spec"] = M.encode_batch(language.parse(sentences.render(t, c)) for t, c in combos)
    return table


@functools.cache
def _table_sentences(has_lava: bool) -> frozenset[str]:
    """Every sentence of the scenarios' table (with lava's rows or without), as spelled."""
    combos = sentences.split_combinations("all", include_lava=has_lava)
    return frozenset(sentences.render(t, c) for t, c in combos)


def _spelled(sentence: str) -> str | None:
    """``sentence`` as the paper's table spells it (:meth:`SentenceTable.find`), or None."""
    try:
        return PAPER.find(sentence).sentence
    except ValueError:
        return None


def sample_constraint(
    u: jax.Array, table: dict, nameable: jax.Array, absent: jax.Array, absent_prob
) -> tuple[DoorConstraint, M.ClauseSpec]:
    """Draw one (template, colour) row of ``table`` from a uniform ``u``: its constraint and
    its monitor encoding.

    With probability ``absent_prob`` the colour is one no door of the episode has (``absent``,
    bool per colour index); otherwise one of the doors the constraint may name (``nameable``).
    Rows within each group are equally likely. If a group has no row in the split (possible
    with ``split="heldout"``), the other group is used.
    """
    colour = jnp.asarray(table["door_colour"])
    present_row = nameable[colour]
    absent_row = absent[colour]
    n_present = jnp.sum(present_row)
    n_absent = jnp.sum(absent_row)
    p = jnp.where(n_present == 0, 1.0, jnp.where(n_absent == 0, 0.0, absent_prob))
    weight = jnp.where(present_row, (1 - p) / jnp.maximum(n_present, 1), 0.0) + jnp.where(
        absent_row, p / jnp.maximum(n_absent, 1), 0.0
    )
    cum = jnp.cumsum(weight)
    row = jnp.argmax(cum > u * cum[-1])
    constraint = DoorConstraint(
        tokens=jnp.asarray(table["tokens"])[row],
        type_id=jnp.asarray(table["paper_type"])[row],
        template_id=jnp.asarray(table["template_id"])[row],
        door_colour=colour[row],
    )
    return constraint, jax.tree.map(lambda a: jnp.asarray(a)[row], table["spec"])


class Scenario(ConstrainedEnvironment):
    """Base of the paper's scenarios: layouts, constraint sampling and the lava rule.

    ``split`` selects the (template, colour) combinations constraints are drawn from
    (``"train"``, ``"heldout"`` or ``"all"``; see :func:`jaxgrid.sentences.split_combinations`).
    ``absent_colour_prob`` (a pytree leaf, so it can be vmapped) is the chance that the
    constraint names a colour no door in the episode has.
    """

    split: str = struct.field(pytree_node=False, default="train")
    absent_colour_prob: float = 0.2
    has_lava: bool = struct.field(pytree_node=False, default=False)
    # Given sentences (rows of the table; jaxgrid.make's constraint=), replacing the split's.
    sentences: tuple[str, ...] | None = struct.field(pytree_node=False, default=None)

    language_table = PAPER

    def __post_init__(self):
        super().__post_init__()
        name = type(self).__name__
        if self.split not in SPLITS:
            raise ValueError(f"{name}.split must be one of {SPLITS}, got {self.split!r}")
        p = self.absent_colour_prob
        if isinstance(p, (int, float)) and not 0 <= p <= 1:
            raise ValueError(f"{name}.absent_colour_prob must be in [0, 1], got {p!r}")
        if self.sentences is not None:
            self._check_sentences(self.sentences)

    def _check_sentences(self, given) -> None:
        name = type(self).__name__
        table = _table_sentences(self.has_lava)
        if isinstance(given, str) or not given:
            raise ValueError(f"{name}.sentences must be a non-empty tuple of sentences, got "
                             f"{given!r}")  # fmt: skip
        for sentence in given:
            if not isinstance(sentence, str) or _spelled(sentence) not in table:
                raise ValueError(
                    f"{sentence!r} is not a sentence of {name}'s table: its layouts are built "
                    f"for the paper's templates with a door colour "
                    f"({len(table)} sentences, listed by jaxgrid.sentences.split_combinations"
                    f"('all', include_lava={self.has_lava}) and render); "
                    "jaxgrid.make(id, constraint=...) constrains its layouts with any other"
                )

    def constraint_table(self) -> dict:
        """:func:`jaxgrid.sentences.combination_table` of the split (of the whole table, only
        the rows of ``sentences``, when given), with ``spec``, each row's
        :class:`~jaxgrid.monitor.ClauseSpec` (``(K, NUM_CLAUSES)`` arrays)."""
        if self.sentences is not None:
            given = tuple(sorted({_spelled(s) for s in self.sentences}))
            return _constraint_table("all", self.has_lava, given)
        return _constraint_table(self.split, self.has_lava)

    def with_sentences(self, given, weights, lava) -> ConstrainedEnvironment:
        """This scenario drawing each episode's constraint from the sentences ``given``.

        Rows of its own table, without ``weights`` or ``lava``: they replace the split's rows,
        every layout holds a run without a violation of each, and the draw and the lava rule
        stay the paper's (a colour no door of the episode has, making that episode's
        constraint vacuous, with ``absent_colour_prob`` where both kinds are among them).
        Otherwise its layouts are constrained as a MiniGrid level is (see the module
        docstring)."""
        table = _table_sentences(self.has_lava)
        if weights is None and lava is None and all(_spelled(s) in table for s in given):
            return self.replace(sentences=tuple(given))
        return self._layouts_constrained(tuple(given), weights, lava, type(self).__name__)

    def with_table(self, table, weights, lava, name) -> ConstrainedEnvironment:
        """Its layouts constrained as a MiniGrid level is, by the rows of ``table`` they can
        hold (a table is no sentence of the paper's)."""
        return self._layouts_constrained(table, weights, lava, name)

    def _layouts_constrained(self, constraints, weights, lava, name) -> ConstrainedEnvironment:
        """:class:`ScenarioLayouts` of this scenario through the one :func:`constrain`."""
        return constrain(ScenarioLayouts.of(self), constraints=constraints, weights=weights,
                         lava=lava, name=name)  # fmt: skip

    def upgrade_extras(self, saved: dict, grid: np.ndarray) -> ScenarioExtras | None:
        """Extras saved before the constraint and monitor moved into
        :class:`~jaxgrid.constrained.ConstrainedExtras` (a constraint of ``tokens``,
        ``template_id``, ``paper_type``, ``door_colour``, ``forbids_lava``, and no monitor):
        each constraint's row of the table gives its monitor, started on the saved grid.
        What follows is judged as before: the paper's clauses forbid doors and lava, which no
        step moves, so the zones are the episode's; their budget is 0, so the events counted
        before the save (not saved; 0 again) change no later cost or violation."""
        old = saved.get("constraint")
        if "monitor" in saved or not isinstance(old, dict) or "paper_type" not in old:
            return None
        table = self.constraint_table()
        batch = np.shape(old["template_id"])
        template = np.asarray(old["template_id"]).reshape(-1)
        colour = np.asarray(old["door_colour"]).reshape(-1)
        match = (template[:, None] == table["template_id"][None]) & (
            colour[:, None] == table["door_colour"][None]
        )
        rows = np.argmax(match, axis=1)
        tokens = np.asarray(old["tokens"]).reshape(len(rows), -1)
        lost = ~match.any(axis=1) | np.any(table["tokens"][rows] != tokens, axis=1)
        if lost.any():
            i = int(np.argmax(lost))
            raise ValueError(
                f"a saved {type(self).__name__} constraint (template {template[i]}, colour "
                f"{colour[i]}) is no row of this environment's table (split={self.split!r}, "
                f"has_lava={self.has_lava})"
            )
        spec = jax.tree.map(lambda a: jnp.asarray(a)[rows], table["spec"])
        radius = int(np.max(table["spec"].radius))
        flat_grid = jnp.asarray(grid).reshape((len(rows),) + np.shape(grid)[len(batch) :])
        monitor = jax.vmap(lambda s, g: M.start(s, g, radius))(spec, flat_grid)
        extras = ScenarioExtras(
            constraint=DoorConstraint(
                tokens=jnp.asarray(tokens, jnp.int32),
                type_id=jnp.asarray(table["paper_type"][rows], jnp.int32),
                template_id=jnp.asarray(template, jnp.int32),
                door_colour=jnp.asarray(colour, jnp.int32),
            ),
            monitor=monitor,
            goal_pos=jnp.asarray(saved["goal_pos"]).reshape(len(rows), 2),
            teleport_pos=jnp.asarray(saved["teleport_pos"]).reshape(len(rows), 2),
        )
        return jax.tree.map(lambda a: a.reshape(batch + a.shape[1:]), extras)

    def layout(self, u: jax.Array):
        """``(grid, agent_pos, goal_pos, nameable door colours, all door colours)``."""
        raise NotImplementedError

    NUM_UNIFORMS = 8

    def draw_layout(self, key: jax.Array):
        """``(u, layout(u), agent direction)`` of an episode's key: the uniforms it spends
        (the last one draws the constraint), the layout and the direction, which
        :class:`ScenarioLayouts` draws too, so that both give the same layouts seed for seed."""
        u = jax.random.uniform(key, (self.NUM_UNIFORMS + 2,))
        return u, self.layout(u), G.randint(u[-2], 0, 4)

    def generate(self, key: jax.Array) -> State:
        u, (grid, agent, goal, nameable, present), direction = self.draw_layout(key)
        all_colours = jnp.arange(6)
        nameable_mask = jnp.any(all_colours[:, None] == nameable[None, :], axis=1)
        absent_mask = ~jnp.any(all_colours[:, None] == present[None, :], axis=1)
        absent_mask = absent_mask & jnp.any(all_colours[:, None] == DOOR_COLOURS[None, :], axis=1)
        table = self.constraint_table()
        constraint, spec = sample_constraint(
            u[-1], table, nameable_mask, absent_mask, self.absent_colour_prob
        )
        extras = ScenarioExtras(
            constraint=constraint,
            # The paper's clauses never grow their zone: no dilation (static, from the table).
            monitor=M.start(spec, grid, int(np.max(table["spec"].radius))),
            goal_pos=goal,
            teleport_pos=_next_to(grid, goal),
        )
        return self.init_state(grid, agent, direction, key, extras)

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """MiniGrid step judged by the monitor, then the lava rule (actions as in
        ``Environment.step``): entering lava that the constraint does not forbid teleports the
        agent next to the goal instead of ending the episode."""
        check_action(action)
        new, reward, terminated, truncated = transition(state, action, self.max_steps)
        new, cost, violation = self.judge(state, new)
        entered = jnp.any(new.agent_pos != state.agent_pos)
        into_lava = entered & (get_cell(new.grid, new.agent_pos)[0] == LAVA)
        teleport = into_lava & ~M.mentions(state.extras.monitor.spec, LAVA)
        new = new.replace(agent_pos=jnp.where(teleport, state.extras.teleport_pos, new.agent_pos))
        terminated = terminated & ~teleport
        info = self.step_info(new, violation, cost)
        return new, self.make_timestep(new, reward, terminated, truncated, info)


class ScenarioLayouts(Environment, kw_only=True):
    """A scenario's layouts as a plain MiniGrid level: the scenario's grid, agent and goal
    seed for seed, MiniGrid's step (lethal lava, no teleport) and no constraint; the level
    that sentences outside the paper's table constrain. Build it with :meth:`of`."""

    scenario: Scenario

    @classmethod
    def of(cls, scenario: Scenario) -> ScenarioLayouts:
        config = ("width", "height", "max_steps", "view_size", "see_through_walls")
        return cls(**{k: getattr(scenario, k) for k in config}, scenario=scenario)

    def min_size(self):
        return self.scenario.min_size()

    def contents(self) -> Contents:
        return self.scenario.contents()

    def generate(self, key: jax.Array) -> State:
        _, (grid, agent, *_), direction = self.scenario.draw_layout(key)
        return self.init_state(grid, agent, direction, key)


def _next_to(grid: jax.Array, pos: jax.Array) -> jax.Array:
    """First empty cell among the left, up, right and down neighbours of ``pos``."""
    offsets = jnp.array([[-1, 0], [0, -1], [1, 0], [0, 1]], jnp.int32)
    cand = pos[None, :] + offsets
    free = jax.vmap(lambda p: get_cell(grid, p)[0] == 1)(cand)
    return cand[jnp.argmax(free)]


def _vertical_wall(grid, xs, x):
    return jnp.where((xs == x)[..., None], jnp.asarray(WALL_CELL), grid)


class TwoRooms(Scenario):
    """Two rooms, one wall with two closed doors of distinct colours (optionally one lava cell)."""

    def min_size(self):
        if self.has_lava:
            # Rooms two columns wide: one lava cell can then never cut the agent off a door.
            return 7, 4, "two rooms at least two columns wide (lava) and two door rows"
        return 5, 4, "two rooms at least one column wide and two door rows"

    def contents(self) -> Contents:
        return Contents(door=sentences.DOOR_COLOURS, lava=self.has_lava)

    def layout(self, u):
        w, h = self.width, self.height
        xs, ys = G.coords(w, h)
        wall_x = w // 2
        grid = _vertical_wall(jnp.asarray(G.room(w, h)), xs, wall_x)
        # Two distinct door rows in 1 .. h-2.
        row1 = G.randint(u[0], 1, h - 1)
        row2 = G.randint(u[1], 1, h - 2)
        row2 = row2 + (row2 >= row1)
        colours = G.distinct(u[2:4], DOOR_COLOURS, 2)
        grid = G.put(grid, (wall_x, row1), G.cell(DOOR, colours[0], CLOSED))
        grid = G.put(grid, (wall_x, row2), G.cell(DOOR, colours[1], CLOSED))
        agent_left = u[4] < 0.5
        left = jnp.asarray(xs < wall_x)
        interior = G.is_empty(grid)
        agent_room = interior & jnp.where(agent_left, left, ~left)
        goal_room = interior & ~agent_room & (jnp.asarray(xs) != wall_x)
        goal = G.sample_cell(u[5], goal_room)
        grid = G.put(grid, goal, GOAL_CELL)
        if self.has_lava:
            # Never in front of a door (either side), so no door approach is ever blocked.
            approach = jnp.zeros((w, h), bool)
            for row in (row1, row2):
                approach = approach | (
                    ((jnp.asarray(xs) == wall_x - 1) | (jnp.asarray(xs) == wall_x + 1))
                    & (jnp.asarray(ys) == row)
                )
            lava = G.sample_cell(u[6], agent_room & ~approach)
            grid = G.put(grid, lava, LAVA_CELL)
            agent_room = agent_room & ~G.at((w, h), lava)
        agent = G.sample_cell(u[7], agent_room)
        return grid, agent, goal, colours, colours


class ThreeRoomsKey(Scenario):
    """Key + locked door to room 2; room 2 -> 3 through a closed door or a bottom-row gap."""

    def min_size(self):
        # Walls at width // 3 and 2 * width // 3 leave every room a column from width 7; the
        # wall-2 door's row (1 .. height - 3) must differ from the gap's (height - 2).
        return 7, 4, "three rooms at least one column wide, a door row above the gap row"

    CONTENTS = Contents(door=sentences.DOOR_COLOURS, key=sentences.DOOR_COLOURS)

    def layout(self, u):
        w, h = self.width, self.height
        xs, ys = G.coords(w, h)
        wall1, wall2 = w // 3, 2 * w // 3
        grid = jnp.asarray(G.room(w, h))
        grid = _vertical_wall(_vertical_wall(grid, xs, wall1), xs, wall2)
        grid = G.put(grid, (wall2, h - 2), np.array([1, 0, 0]))  # the gap: the longer route
        colours = G.distinct(u[0:2], DOOR_COLOURS, 2)  # [locked door/key, wall-2 door]
        locked_row = G.randint(u[2], 1, h - 1)
        door_row = G.randint(u[3], 1, h - 2)  # never the gap row
        grid = G.put(grid, (wall1, locked_row), G.cell(DOOR, colours[0], LOCKED))
        grid = G.put(grid, (wall2, door_row), G.cell(DOOR, colours[1], CLOSED))
        goal = jnp.array([w - 2, 1], jnp.int32)
        grid = G.put(grid, goal, GOAL_CELL)
        room1 = G.is_empty(grid) & jnp.asarray(xs < wall1)
        agent = G.sample_cell(u[4], room1)
        key_pos = G.sample_cell(u[5], room1 & ~G.at((w, h), agent))
        grid = G.put(grid, key_pos, G.cell(KEY, colours[0], 0))
        return grid, agent, goal, colours[1:], colours
