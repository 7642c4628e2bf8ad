"""``HazardRooms-v0``: four rooms with costly hazards, under a rich language constraint.

One thing, a single environment (layout, constraint draw and its retry loop), hence its length.

A grid (13x13 for the registered id, 9x9 at least) split into four rooms by a cross of
walls, with one closed door in each of the four wall segments (four distinct colours of the
five non-green ones). The agent starts in one room and the goal lies in the opposite one, so
there are two routes, each through two doors. A key lies in the agent's room. Strips of three
cells of lava and of coloured floor ("water" is blue, "grass" green, and yellow floor) are
scattered over the rooms, never on the cells in front of a door, the agent, the goal or the
key. Lava costs instead of killing: the
agent walks on it as on floor, and only the constraint makes it a hazard.

Each episode draws a constraint of :mod:`jaxgrid.language`: its type uniformly among avoid,
budget, sequential, proximity and conjunction, then a sentence uniformly among the rows of
that type of its table (:data:`jaxgrid.sentences.HAZARD_ROOMS`; a conjunction joins two
clauses of uniform types with "and"). The
layout is then drawn until the goal can be reached without entering any clause's forbidden
zone (every budget, trigger and order ignored: a sufficient condition for a run with no
violation) and every trigger cell the constraint names exists; after
:data:`TRIES_PER_SENTENCE` failed layouts another sentence of the same type is drawn (types
stay uniform; within a type, sentences that few layouts satisfy become rarer), and after
:data:`MAX_TRIES` the last layout is kept, and ``info["satisfiable"]`` is False for that whole
episode, so evaluation can count such episodes. The agent starts outside every zone whenever
the layout is satisfiable. So that
budgets and sequences bind, most strips (:data:`NAMED_SHARE`) are of the ground hazard a
budget or sequential clause names first, and the trigger of an "after" clause, when it is to
enter lava or a floor, lies on both doorsteps out of the agent's room: a route that skirts its
trigger never arms the clause. The monitor (:mod:`jaxgrid.monitor`) lives in the
state; ``info`` reports ``violation``, ``cost``, ``constraint_type`` (index into
:data:`jaxgrid.language.CONSTRAINT_TYPES`), ``template_id`` (the first clause's) and
``satisfiable``.

``sentences`` replaces the drawn constraints with a fixed list (each episode draws one of
them, uniformly or by ``weights``; ``jaxgrid.make("HazardRooms-v0", constraint=...)`` sets
them); every sentence is parsed and checked against what the scenario contains
(:attr:`HazardRooms.CONTENTS`) when the environment is built, and refused when fewer than
:data:`MIN_SATISFIABLE_SHARE` of :data:`CHECK_LAYOUTS` sampled layouts can be crossed without
entering its zones (:func:`satisfiable_share`): the retry loop would often end on an
impossible layout.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import grid as G
from jaxgrid import language
from jaxgrid import monitor as M
from jaxgrid.constants import (
    BLUE,
    CLOSED,
    COLOR_TO_IDX,
    DOOR,
    EMPTY_CELL,
    FLOOR,
    GOAL,
    GOAL_CELL,
    GREEN,
    KEY,
    LAVA,
    LAVA_CELL,
    WALL_CELL,
    YELLOW,
)
from jaxgrid.constrained import (
    ConstrainedEnvironment,
    ConstrainedExtras,
    EpisodeConstraint,
    check_lava,
    check_weights,
    draw_row,
    harmless_lava,
)
from jaxgrid.contents import ALL_COLOURS, Contents
from jaxgrid.dynamics import transition
from jaxgrid.environment import check_action
from jaxgrid.oracle import distance_field, passable_cells
from jaxgrid.paraphrases import SPLITS
from jaxgrid.scenarios import DOOR_COLOURS
from jaxgrid.sentences import (
    HAZARD_ROOMS,
    HAZARD_ROOMS_FLOORS,
    HAZARD_ROOMS_TARGETS,
    hazard_rooms_rows,
)
from jaxgrid.types import State, TimeStep

#: Layout draws per episode before the last one is kept whatever it is.
MAX_TRIES = 128
#: Layout draws per sentence: a sentence no layout satisfies is replaced by another of its type.
TRIES_PER_SENTENCE = 16
#: Layouts sampled (from fixed keys) to measure how often a given sentence can be met.
CHECK_LAYOUTS = 256
#: Least share of layouts a given sentence must leave a zone-free route in. At 5% the retry
#: loop ends on an impossible layout in about one episode of 700 (0.95 ** MAX_TRIES); every
#: row of the default tables measures 15% or more on the 13x13 grid.
MIN_SATISFIABLE_SHARE = 0.05
#: Chance that a strip is of the ground hazard that a budget or sequential clause names first.
NAMED_SHARE = 0.75
#: Colours of the floor tiles (MiniGrid indices): water, grass and yellow floor.
FLOOR_COLOURS = tuple(COLOR_TO_IDX[c] for c in HAZARD_ROOMS_FLOORS)
#: (kind, colour) of each hazard strip, in drawing order (later strips paint over earlier).
STRIPS = (
    (LAVA, 0), (LAVA, 0), (LAVA, 0), (FLOOR, BLUE), (FLOOR, BLUE),
    (FLOOR, BLUE), (FLOOR, GREEN), (FLOOR, GREEN), (FLOOR, YELLOW), (FLOOR, YELLOW),
)  # fmt: skip
_STRIP_LEN = 3
# The two rooms each door joins: doors 0 and 1 in the vertical wall, 2 and 3 in the horizontal.
_DOOR_ROOMS = ((0, 1), (2, 3), (0, 2), (1, 3))


def check_sentence(sentence: str) -> language.Constraint:
    """Parse ``sentence`` and check that HazardRooms has what it names.

    Raises ``ValueError`` naming the word for a target or trigger the scenario lacks
    (:attr:`HazardRooms.CONTENTS`): a ball or box, a floor colour other than blue, green and
    yellow, a green door.
    """
    c = language.parse(sentence)
    HazardRooms.CONTENTS.check(c, "HazardRooms")
    return c


def _rows_to_arrays(rows: list[tuple[str, language.Constraint, int, int]]) -> dict:
    """Numeric table: ``tokens``, ``length``, ``type_id``, ``template_id``, ``target_id`` and
    ``spec`` (a :class:`~jaxgrid.monitor.ClauseSpec` of ``(R, NUM_CLAUSES)`` arrays)."""
    targets = HAZARD_ROOMS_TARGETS
    return {
        "tokens": HAZARD_ROOMS.tokenize_batch(s for s, *_ in rows),
        "length": np.array([len(s.split()) for s, *_ in rows], np.int32),
        "type_id": np.array([c.type_id for _, c, _, _ in rows], np.int32),
        "template_id": np.array([t for *_, t, _ in rows], np.int32),
        "target_id": np.array(
            [
                targets.index(c.clauses[0].target) if c.clauses[0].target in targets else -1
                for _, c, _, _ in rows
            ],
            np.int32,
        ),  # fmt: skip
        "spec": M.encode_batch(c for _, c, _, _ in rows),
    }


@functools.cache
def _default_table(split: str, budgets: tuple, distances: tuple) -> dict:
    rows = hazard_rooms_rows(split, budgets, distances)
    return _rows_to_arrays(
        [(r.sentence, language.Constraint((r.clause,), r.sentence), r.template_id, 0)
         for r in rows]
    )  # fmt: skip


@functools.cache
def _sentence_table(sentences: tuple[str, ...]) -> dict:
    rows = []
    for s in sentences:
        c = check_sentence(s)
        rows.append((" ".join(language.normalize(s)), c, -1, 0))
    return _rows_to_arrays(rows)


@struct.dataclass
class HazardExtras(ConstrainedExtras):
    """The constraint (``type_id`` an index into :data:`jaxgrid.language.CONSTRAINT_TYPES`,
    ``template_id`` the first clause's, -1 for a given sentence) and monitor, and the goal."""

    goal_pos: jax.Array  # int32 (2,)
    satisfiable: jax.Array  # bool: the goal is reachable without entering any zone


def _on_the_ground(kind: jax.Array) -> jax.Array:
    """Whether an object kind is a ground hazard (lava or a floor), walked over, not a door."""
    return (kind == LAVA) | (kind == FLOOR)


def _pick(u: jax.Array, mask: jax.Array) -> jax.Array:
    """Uniform index among the True entries of a 1-D ``mask`` (which has at least one)."""
    cum = jnp.cumsum(mask.astype(jnp.int32))
    r = jnp.minimum(jnp.floor(u * cum[-1]).astype(jnp.int32), cum[-1] - 1)
    return jnp.argmax(cum > r).astype(jnp.int32)


def _join(tok_a, len_a, tok_b, len_b):
    """Tokens of "<a> and <b>" from two right-padded rows."""
    pos = jnp.arange(tok_a.shape[-1])
    j = jnp.clip(pos - len_a - 1, 0, tok_a.shape[-1] - 1)
    and_id = language.VOCAB.index("and")
    tail = jnp.where(pos - len_a - 1 < len_b, tok_b[j], 0)
    return jnp.where(pos < len_a, tok_a, jnp.where(pos == len_a, and_id, tail))


def _slot(spec: M.ClauseSpec, row, slot: int) -> M.ClauseSpec:
    return jax.tree.map(lambda a: a[row, slot], spec)


class HazardRooms(ConstrainedEnvironment):
    """Four rooms, doors, a key, costly lava and floor strips, a rich constraint per episode.

    Static settings: ``split`` (table rows drawn from, as the paper's scenarios), ``budgets``
    (the counts budget clauses use), ``distances`` (those proximity clauses use),
    ``sentences`` (a fixed list of constraints instead of the drawn ones) and ``weights``
    (how often each of them is drawn; None: uniformly).
    """

    split: str = struct.field(pytree_node=False, default="train")
    budgets: tuple = struct.field(pytree_node=False, default=(1, 2))
    distances: tuple = struct.field(pytree_node=False, default=(2, 3))
    sentences: tuple | None = struct.field(pytree_node=False, default=None)
    weights: tuple | None = struct.field(pytree_node=False, default=None)

    language_table = HAZARD_ROOMS
    INFO_KEYS = ConstrainedEnvironment.INFO_KEYS + ("satisfiable",)

    def __post_init__(self):
        super().__post_init__()
        name = type(self).__name__
        if self.split not in SPLITS:
            raise ValueError(f"{name}.split must be one of {SPLITS}, got {self.split!r}")
        for field, hi in (("budgets", language.MAX_BUDGET), ("distances", language.MAX_DISTANCE)):
            values = getattr(self, field)
            if (
                not isinstance(values, tuple)
                or not values
                or any(
                    isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= hi
                    for v in values
                )
            ):
                raise ValueError(f"{name}.{field} must be a non-empty tuple of ints 1..{hi}")
        if self.sentences is not None:
            if isinstance(self.sentences, str) or not self.sentences:
                raise ValueError(f"{name}.sentences must be a non-empty tuple of sentences")
            self.constraint_table()  # parses and checks every sentence now
            if self.weights is not None:
                check_weights(self.weights, len(self.sentences))
            for sentence in dict.fromkeys(self.sentences):
                _check_satisfiable(self, sentence)
        elif self.weights is not None:
            raise ValueError(f"{name}.weights needs sentences: they weigh the given sentences")

    #: Its doors (the five non-green colours), lava, water, grass and yellow floor, a key.
    CONTENTS = Contents(
        door=[t.colour for t in HAZARD_ROOMS_TARGETS if t.kind == "door"],
        lava=True, floor=HAZARD_ROOMS_FLOORS, key=ALL_COLOURS,
    )  # fmt: skip

    def with_sentences(self, sentences, weights, lava):
        """HazardRooms drawing from ``sentences`` (its lava always costs: ``lava`` must be None
        or ``"cost"``)."""
        if lava not in (None, "cost"):
            check_lava(lava)
            raise ValueError(f"HazardRooms' lava always costs; lava={lava!r} is not available")
        return self.replace(sentences=tuple(sentences), weights=weights)

    def min_size(self):
        # Every room interior at least 3x3: room for a strip and a cell beside each door.
        return 9, 9, "four rooms of at least 3x3 cells (a hazard strip is 3 cells long)"

    @property
    def every_sentence_in_table(self) -> bool:
        """Whether :meth:`constraint_table` lists every sentence an episode can say: only with
        ``sentences``; drawn conjunctions join two of its rows at reset."""
        return self.sentences is not None

    def constraint_table(self) -> dict:
        """The numeric table constraints are drawn from (see :func:`_rows_to_arrays`)."""
        if self.sentences is not None:
            return _sentence_table(tuple(self.sentences))
        return _default_table(self.split, tuple(self.budgets), tuple(self.distances))

    # --- layout ---------------------------------------------------------------------------
    def layout(self, u: jax.Array, named: jax.Array | None = None,
               doorstep: jax.Array | None = None):  # fmt: skip
        """``(grid, agent, direction, goal)`` of one draw from uniforms ``u``.

        ``named``: int32 ``(2,)`` (kind, colour) of the ground hazard the constraint names
        first, or kind -1; each strip is of that hazard with probability :data:`NAMED_SHARE`.
        ``doorstep``: int32 ``(2,)`` (kind, colour) of a ground cell laid in front of both
        doors out of the agent's room, on every route, or kind -1 (none).
        """
        w, h = self.width, self.height
        mx, my = w // 2, h // 2  # the cross of walls
        xs, ys = G.coords(w, h)
        grid = jnp.asarray(G.room(w, h))
        grid = jnp.where(((xs == mx) | (ys == my))[..., None], jnp.asarray(WALL_CELL), grid)
        colours = G.distinct(u[0:4], DOOR_COLOURS, 4)
        # Doors: top and bottom of the vertical wall, left and right of the horizontal one.
        doors = [
            (mx, G.randint(u[4], 1, my)),
            (mx, G.randint(u[5], my + 1, h - 1)),
            (G.randint(u[6], 1, mx), my),
            (G.randint(u[7], mx + 1, w - 1), my),
        ]
        protect = jnp.zeros((w, h), bool)
        for (dx, dy), colour in zip(doors, colours, strict=True):
            grid = G.put(grid, (dx, dy), G.cell(DOOR, colour, CLOSED))
            protect = protect | ((jnp.abs(xs - dx) + jnp.abs(ys - dy)) == 1)
        # Rooms 0 1 / 2 3 (room 3 - r is opposite room r): origin and size of each interior.
        left, top = np.array([1, mx + 1, 1, mx + 1]), np.array([1, 1, my + 1, my + 1])
        room_w, room_h = (
            np.array([mx - 1, w - 2 - mx] * 2),
            np.array([my - 1] * 2 + [h - 2 - my] * 2),
        )
        rooms = jnp.stack([
            (xs >= x0) & (xs < x0 + rw) & (ys >= y0) & (ys < y0 + rh)
            for x0, y0, rw, rh in zip(left, top, room_w, room_h, strict=True)
        ])  # fmt: skip
        agent_room = G.randint(u[8], 0, 4)
        agent = G.sample_cell(u[9], rooms[agent_room] & ~protect)
        goal = G.sample_cell(u[10], rooms[3 - agent_room] & ~protect)
        key = G.sample_cell(u[11], rooms[agent_room] & ~protect & ~G.at((w, h), agent))
        protect = protect | G.at((w, h), agent) | G.at((w, h), goal) | G.at((w, h), key)
        grid = G.put(grid, goal, GOAL_CELL)
        grid = G.put(grid, key, G.cell(KEY, G.randint(u[12], 0, 6), 0))
        named = jnp.array([-1, 0], jnp.int32) if named is None else named
        n = len(STRIPS)

        def paint(grid, strip):
            kind, colour, v, named_u = strip
            use_named = (named[0] >= 0) & (named_u < NAMED_SHARE)
            kind = jnp.where(use_named, named[0], kind)
            colour = jnp.where(use_named, named[1], colour)
            r = G.randint(v[0], 0, 4)
            across = v[1] < 0.5  # a horizontal strip
            rw, rh = jnp.asarray(room_w)[r], jnp.asarray(room_h)[r]
            # First cell, in room coordinates: along the strip, then across it.
            a = G.randint(v[2], 0, jnp.where(across, rw, rh) - _STRIP_LEN + 1)
            b = G.randint(v[3], 0, jnp.where(across, rh, rw))
            dx = xs - jnp.asarray(left)[r] - jnp.where(across, a, b)
            dy = ys - jnp.asarray(top)[r] - jnp.where(across, b, a)
            strip = jnp.where(
                across,
                (dy == 0) & (dx >= 0) & (dx < _STRIP_LEN),
                (dx == 0) & (dy >= 0) & (dy < _STRIP_LEN),
            )
            cell = jnp.where(kind == LAVA, jnp.asarray(LAVA_CELL), G.cell(FLOOR, colour, 0))
            return jnp.where((strip & ~protect)[..., None], cell, grid), None

        if doorstep is not None:  # before the strips' loop, which never paints a doorstep
            # The cell inside room r in front of each door (door i joins rooms _DOOR_ROOMS[i]).
            steps = jnp.zeros((w, h), bool)
            for i, ((dx, dy), rooms_i) in enumerate(zip(doors, _DOOR_ROOMS, strict=True)):
                for r in rooms_i:
                    step = (dx + (r % 2) * 2 - 1, dy) if i < 2 else (dx, dy + (r // 2) * 2 - 1)
                    steps = steps | (G.at((w, h), step) & (agent_room == r))
            kind, colour = doorstep[0], doorstep[1]
            cell = jnp.where(kind == LAVA, jnp.asarray(LAVA_CELL), G.cell(FLOOR, colour, 0))
            grid = jnp.where((steps & (kind >= 0))[..., None], cell, grid)

        # A loop, not ten unrolled selects: its output is a buffer. Unrolled, XLA fuses the
        # whole chain into every consumer, and the monitor's dilations and the BFS read each
        # cell at several shifts, so each read recomputed the layout (a reset 7-26x slower,
        # docs/decisions.md); the loop gives the same bits.
        kinds, colours = (jnp.asarray(c, jnp.int32) for c in zip(*STRIPS, strict=True))
        strips = (kinds, colours, u[13 : 13 + 4 * n].reshape(n, 4), u[15 + 4 * n : 15 + 5 * n])
        grid, _ = jax.lax.scan(paint, grid, strips)
        direction = G.randint(u[14 + 4 * n], 0, 4)
        return grid, agent, direction, goal

    NUM_UNIFORMS = 15 + 5 * len(STRIPS)

    # --- constraint -----------------------------------------------------------------------
    def _draw_constraint(self, key: jax.Array, table: dict, ctype: jax.Array):
        """``(EpisodeConstraint, ClauseSpec)`` of type ``ctype``, as the module docstring says."""
        u = jax.random.uniform(key, (6,))
        spec = table["spec"]
        if self.sentences is not None:
            if self.weights is None:
                row = _pick(u[0], jnp.ones(table["type_id"].shape, bool))
            else:
                row = draw_row(u[0], jnp.cumsum(jnp.asarray(self.weights, jnp.float32)))
            ec = EpisodeConstraint(
                table["tokens"][row], table["type_id"][row], table["template_id"][row]
            )
            return ec, jax.tree.map(lambda a: a[row], spec)
        type_ids = jnp.asarray(table["type_id"])
        conj = ctype == language.CONSTRAINT_TYPES.index("conjunction")
        type_a = jnp.where(conj, G.randint(u[1], 0, len(language.CLAUSE_TYPES)), ctype)
        type_b = G.randint(u[2], 0, len(language.CLAUSE_TYPES))
        a = _pick(u[3], type_ids == type_a)
        targets = jnp.asarray(table["target_id"])
        b = _pick(u[4], (type_ids == type_b) & (targets != targets[a]))
        tokens = jnp.asarray(table["tokens"])
        length = jnp.asarray(table["length"])
        joined = _join(tokens[a], length[a], tokens[b], length[b])
        second = jax.tree.map(
            lambda x, unused: jnp.where(conj, x, unused), _slot(spec, b, 0), M.empty_slot()
        )
        first = _slot(spec, a, 0)
        clause_spec = jax.tree.map(lambda x, y: jnp.stack([x, y]), first, second)
        ec = EpisodeConstraint(
            tokens=jnp.where(conj, joined, tokens[a]),
            type_id=ctype,
            template_id=jnp.asarray(table["template_id"])[a],
        )
        return ec, clause_spec

    def _attempt(self, table: dict, ctype: jax.Array, key_c: jax.Array, key_l: jax.Array, i):
        """Draw ``i`` of an episode: ``(constraint, grid, agent, direction, goal, monitor, ok)``,
        the constraint as :meth:`_draw_constraint` says and the layout as :meth:`_lay_out`."""
        # A fresh sentence of the same type every TRIES_PER_SENTENCE layouts.
        ec, spec = self._draw_constraint(
            jax.random.fold_in(key_c, i // TRIES_PER_SENTENCE), table, ctype
        )
        return (ec, *self._lay_out(spec, jax.random.fold_in(key_l, i)))

    def _lay_out(self, spec: M.ClauseSpec, key: jax.Array):
        """``(grid, agent, direction, goal, monitor, ok)``: one layout drawn for ``spec``.

        ``ok``: the goal is reachable without entering any clause's zone and every trigger cell
        the constraint names exists. Layouts from independent keys are independent, so a batch
        of them measures how often a constraint can be met (:func:`satisfiable_share`).
        """
        first = jax.tree.map(lambda a: a[0], spec)
        ground = _on_the_ground(first.target_kind)
        # Budgets and sequences bind only when their hazard lies across the route; avoid
        # and proximity clauses bind often enough with the plain layout, and are harder to
        # satisfy with more of their hazard.
        boost = ground & ((first.budget > 0) | (first.gate != M.ALWAYS))
        named = jnp.stack([jnp.where(boost, first.target_kind, -1), first.target_colour])
        # An "after" clause binds only when the route meets its trigger first: a ground
        # trigger lies on the doorsteps out of the agent's room, so every route meets it.
        on_route = (
            (first.gate == M.AFTER) & ~first.trigger_pickup & _on_the_ground(first.trigger_kind)
        )
        doorstep = jnp.stack([jnp.where(on_route, first.trigger_kind, -1), first.trigger_colour])
        u = jax.random.uniform(key, (self.NUM_UNIFORMS,))
        grid, agent, direction, goal = self.layout(u, named, doorstep)
        monitor = M.start(spec, grid)
        ok = solvable(grid, agent, jnp.any(monitor.zone, 0))
        # A trigger to enter must exist ("after you pass the purple door" with no purple
        # door would never arm), as must the key for a pickup trigger (it always does).
        enters = spec.active & (spec.trigger_kind >= 0) & ~spec.trigger_pickup
        ok = ok & jnp.all(~enters | jnp.any(monitor.trigger_cells, axis=(1, 2)))
        return grid, agent, direction, goal, monitor, ok

    def generate(self, key: jax.Array) -> State:
        table = jax.tree.map(jnp.asarray, self.constraint_table())
        key_t, key_c, key_l = jax.random.split(key, 3)
        ctype = G.randint(jax.random.uniform(key_t), 0, len(language.CONSTRAINT_TYPES))

        def cond(carry):
            i, *_, ok = carry
            return ~ok & (i < MAX_TRIES)

        def body(carry):
            i = carry[0]
            return (i + 1, *self._attempt(table, ctype, key_c, key_l, i))

        draw0 = self._attempt(table, ctype, key_c, key_l, 0)
        _, ec, grid, agent, direction, goal, monitor, ok = jax.lax.while_loop(
            cond, body, (jnp.int32(1), *draw0)
        )
        extras = HazardExtras(constraint=ec, monitor=monitor, goal_pos=goal, satisfiable=ok)
        return self.init_state(grid, agent, direction, key, extras)

    # --- step -----------------------------------------------------------------------------
    def step_info(self, state: State, violation: jax.Array, cost: jax.Array) -> dict:
        """The constrained info, and ``satisfiable``: whether the episode's layout has a run
        with no violation."""
        return {
            **super().step_info(state, violation, cost),
            "satisfiable": state.extras.satisfiable,
        }

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """MiniGrid step with harmless lava, and the monitor's cost and violation."""
        check_action(action)
        new, reward, terminated, truncated = transition(state, action, self.max_steps)
        terminated = harmless_lava(state, new, terminated)
        new, cost, violation = self.judge(state, new)
        info = self.step_info(new, violation, cost)
        return new, self.make_timestep(new, reward, terminated, truncated, info)


def _layout_env(env: HazardRooms) -> HazardRooms:
    """``env`` with the settings that never shape a layout set to fixed values, so that envs
    differing only in them share one compiled check: steps and views (``max_steps``,
    ``view_size``, ``see_through_walls``) and the constraint table (the spec is an input)."""
    return env.replace(
        sentences=None, weights=None, max_steps=1, view_size=7, see_through_walls=False
    )


@functools.cache
def _share_fn(env: HazardRooms):
    # lax.map, not vmap: the same answers, and it compiles in about two thirds of the time.
    return jax.jit(lambda spec, keys: jax.lax.map(lambda k: env._lay_out(spec, k)[-1], keys))


@functools.cache
def _share(env: HazardRooms, sentence: str, n: int) -> float:
    spec = M.encode(check_sentence(sentence))
    keys = jax.random.split(jax.random.key(0), n)
    return float(np.mean(_share_fn(env)(spec, keys)))


def satisfiable_share(env: HazardRooms, sentence: str, n: int = CHECK_LAYOUTS) -> float:
    """Share of ``n`` layouts of ``env`` drawn for ``sentence`` in which the goal is reachable
    without entering any of its zones (and its enter-triggers exist): each such layout has a
    run with no violation.

    Layouts come from fixed keys, so the share is reproducible; it is cached per layout
    settings and sentence. The first call for a grid size compiles the layout (seconds on a
    CPU); later ones take milliseconds. Raises as :func:`check_sentence` does.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n must be a positive int, got {n!r}")
    return _share(_layout_env(env), sentence, n)


def _check_satisfiable(env: HazardRooms, sentence: str) -> None:
    """Raise ``ValueError`` naming ``sentence`` when too few sampled layouts can be crossed
    without entering its zones (see :data:`MIN_SATISFIABLE_SHARE`)."""
    share = satisfiable_share(env, sentence)
    if share < MIN_SATISFIABLE_SHARE:
        raise ValueError(
            f"{type(env).__name__}.sentences: {sentence!r} can rarely be met: only {share:.1%} "
            f"of {CHECK_LAYOUTS} sampled {env.width}x{env.height} layouts have a route to the "
            f"goal outside its forbidden zones (at least {MIN_SATISFIABLE_SHARE:.0%} needed), "
            f"so many episodes would have no run without a violation; choose a weaker "
            "constraint (a smaller distance, one clause) or a larger grid"
        )


def solvable(grid: jax.Array, agent: jax.Array, forbidden: jax.Array) -> jax.Array:
    """Whether the goal can be reached from ``agent`` without entering ``forbidden`` cells.

    The oracle's cells (:func:`jaxgrid.oracle.passable_cells` with empty hands, no forbidden
    door colour, lava walkable): closed doors count as passable (they can be opened), locked
    ones do not. The agent's own cell and the goal's must be allowed.
    """
    kind = grid[..., 0]
    passable = passable_cells(grid, jnp.asarray(EMPTY_CELL), -1, avoid_lava=False) & ~forbidden
    dist = distance_field((kind == GOAL) & ~forbidden, passable)
    inf = grid.shape[0] * grid.shape[1] + 1
    return (dist[agent[0], agent[1]] < inf) & ~forbidden[agent[0], agent[1]]
