"""MiniGrid's single-room mission levels (GoToDoor, GoToObject, Fetch, PutNear), generated
natively, with their own step rules.

Each ``generate`` mirrors the ``_gen_grid`` of the MiniGrid class it names; the comments quote
the MiniGrid call each line reproduces. MiniGrid draws objects by rejection, and each draw is
taken here from the distribution the rejection converges to, with no retry loop:

* an object's type and colour (``_rand_elem(types)``, ``_rand_elem(COLOR_NAMES)``) are a
  uniform (type, colour) pair; where MiniGrid redraws a pair already placed ("if (objType,
  objColor) in objs: continue"; GoToDoor: a colour already taken), the draw is uniform among
  the pairs (colours) not taken yet;
* ``place_obj``/``place_agent`` are uniform among the cells they accept (empty, and for
  PutNear not next to an object placed before, ``reject_fn=near_obj``; the agent is placed
  last, so objects never avoid it);
* "redraw the target until it differs from the object to move" is a uniform choice among the
  other objects.

MiniGrid never gives up (``max_tries=math.inf``), so a size where a draw may find no cell
loops forever there; such sizes are refused here (each class's ``min_size``).

The levels override ``MiniGridEnv.step`` in MiniGrid and here alike: each class applies
MiniGrid's rule after :func:`jaxgrid.dynamics.transition` (see :meth:`MissionLevel.rule`).
Success pays ``1 - 0.9 * step_count / max_steps``. The task is kept in ``state.extras``: a
:class:`~jaxgrid.levels.keys.Mission` (GoToDoor, GoToObject), a :class:`FetchMission` or a
:class:`PutNearMission`, from which :meth:`~jaxgrid.environment.Environment.mission` spells
MiniGrid's mission string. As in MiniGrid, stepping on after termination applies the rule
again. Actions outside ``0..6`` act as ``done`` (MiniGrid raises on them), for the rule too.
:data:`IDS` maps MiniGrid's ids, with MiniGrid's per-id defaults, to factories.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from jaxgrid import grid as G
from jaxgrid import mission as mission_words
from jaxgrid.constants import (
    BALL,
    BOX,
    CLOSED,
    DONE,
    DOOR,
    DROP,
    EMPTY,
    EMPTY_CELL,
    KEY,
    PICKUP,
    TOGGLE,
    WALL_CELL,
)
from jaxgrid.contents import ALL_COLOURS, Contents
from jaxgrid.dynamics import front_pos, transition
from jaxgrid.environment import Environment, check_action
from jaxgrid.levels.keys import Mission, mission
from jaxgrid.types import State, TimeStep

NUM_COLOURS = 6  # MiniGrid's COLOR_NAMES
KEY_BALL_BOX = (KEY, BALL, BOX)  # types = ["key", "ball", "box"]
KEY_BALL = (KEY, BALL)  # self.obj_types = ["key", "ball"] (Fetch)


@struct.dataclass
class FetchMission(Mission):
    """Fetch's task: the target's :class:`Mission` and which of MiniGrid's five phrasings
    (:data:`FETCH_PHRASINGS`) the mission string uses, int32."""

    phrasing: jax.Array


# FetchEnv: idx = self._rand_int(0, 5); "get a %s", "go get a %s", ... % descStr
FETCH_PHRASINGS = ("get a", "go get a", "fetch a", "go fetch a", "you must fetch a")


@struct.dataclass
class PutNearMission:
    """PutNear's task: MiniGrid's ``move_type``/``moveColor``/``move_pos`` and
    ``target_type``/``target_color``/``target_pos``, as two :class:`Mission`. Both ``pos`` are
    the cells the objects were placed on; the rule reads the target's, wherever the target is
    later."""

    move: Mission
    target: Mission


def _draw_distinct(u: jax.Array, n: int) -> jax.Array:
    """int32 ``(len(u),)`` values in ``0 .. n - 1``, each uniform among those not drawn before
    (MiniGrid's "draw; if already drawn: draw again"). ``len(u)`` must not exceed ``n``."""

    def draw(used, u_i):
        free = ~used
        k = G.randint(u_i, 0, jnp.sum(free, dtype=jnp.int32))
        value = jnp.argmax(jnp.cumsum(free) > k).astype(jnp.int32)  # the k-th free value
        return used | (jnp.arange(n) == value), value

    return jax.lax.scan(draw, jnp.zeros(n, bool), u)[1]


def _adjacent(a, b) -> jax.Array:
    # (ax == tx and abs(ay - ty) == 1) or (ay == ty and abs(ax - tx) == 1)
    return jnp.sum(jnp.abs(a - b)) == 1


def _check_int(level, field: str, low: int, high: int | None, why: str) -> None:
    value = getattr(level, field)
    if (
        not isinstance(value, int)
        or isinstance(value, bool)
        or value < low
        or (high is not None and value > high)
    ):
        bound = f">= {low}" if high is None else f"in {low}..{high}"
        raise ValueError(
            f"{type(level).__name__}.{field} must be an int {bound} ({why}), got {value!r}"
        )


# ------------------------------------------------------------------------------- base


class MissionLevel(Environment):
    """A level whose ``step`` is ``MiniGridEnv.step`` followed by its own rule."""

    def rule(
        self, before: State, after: State, action: jax.Array, reward, terminated
    ) -> tuple[jax.Array, jax.Array]:
        """MiniGrid's override: ``(reward, terminated)`` after the step from ``before`` to
        ``after`` with ``action`` (int32), given ``MiniGridEnv.step``'s own."""
        raise NotImplementedError

    def success_reward(self, state: State) -> jax.Array:
        """``self._reward()``: ``1 - 0.9 * (step_count / max_steps)``."""
        return 1.0 - 0.9 * (state.step_count.astype(jnp.float32) / self.max_steps)

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """``MiniGridEnv.step``, then the level's :meth:`rule`."""
        check_action(action)
        action = jnp.asarray(action, jnp.int32)
        after, reward, terminated, truncated = transition(state, action, self.max_steps)
        # an action outside 0..6 acts as done, for the rule too
        action = jnp.where((action >= 0) & (action < DONE), action, DONE)
        reward, terminated = self.rule(state, after, action, reward, terminated)
        return after, self.make_timestep(after, reward.astype(jnp.float32), terminated, truncated)


class _GoTo(MissionLevel):
    """GoToDoor's and GoToObject's rule: ``toggle`` ends the episode; ``done`` ends it, with
    the success reward if the agent stands next to (4-neighbour, any direction) the cell
    ``state.extras.pos`` (MiniGrid's ``target_pos``: where the target was placed, even if it
    was moved or opened since)."""

    def rule(self, before, after, action, reward, terminated):
        # if action == self.actions.done: if <agent next to target_pos>: reward = self._reward()
        done = action == DONE
        success = done & _adjacent(after.agent_pos, after.extras.pos)
        reward = jnp.where(success, self.success_reward(after), reward)
        # if action == self.actions.toggle: terminated = True; done: terminated = True
        return reward, terminated | done | (action == TOGGLE)


# ---------------------------------------------------------------------------- GoToDoor


class GoToDoor(_GoTo):
    """``GoToDoorEnv``: a room with a closed door in each wall; go next to the door of the
    mission's colour and perform ``done``.

    The room's width and height are uniform in ``5 .. width`` and ``5 .. height`` (MiniGrid's
    ``size``), its top-left corner at ``(0, 0)``; cells right of and below it stay empty. The
    top and bottom doors lie at a uniform column ``2 .. room_width - 3``, the left and right
    ones at a uniform row ``2 .. room_height - 3``; their colours are four distinct colours,
    each uniform among those not yet taken. The agent stands uniformly inside the room with a
    uniform direction; the target door is uniform among the four. ``state.extras`` is a
    :class:`~jaxgrid.levels.keys.Mission` (the door, its colour and cell).

    Step (``GoToDoorEnv.step``): ``toggle`` terminates (it opens the door faced, as
    ``MiniGridEnv.step`` does, before ending the episode); ``done`` terminates, with the
    success reward when the agent is next to the target door. MiniGrid builds square sizes
    only, with ``see_through_walls=True``. After a toggle ended the episode, an agent that
    walks through a door on the grid's border and faces out of the grid makes MiniGrid raise
    (``Grid.get``); here the outside reads as a wall.
    """

    def mission(self, state: State) -> jax.Array:
        return mission_words.fill("go to the {colour} door", colour=state.extras.colour)

    def min_size(self):
        return 5, 5, "GoToDoorEnv asserts size >= 5: doors at least two cells from each corner"

    CONTENTS = Contents(door=ALL_COLOURS)

    def generate(self, key: jax.Array) -> State:
        w, h = self.width, self.height
        u = jax.random.uniform(key, (14,))
        # width = _rand_int(5, width + 1); height = _rand_int(5, height + 1)
        rw, rh = G.randint(u[0], 5, w + 1), G.randint(u[1], 5, h + 1)
        xs, ys = G.coords(w, h)
        # grid.wall_rect(0, 0, width, height)
        inside = (xs < rw) & (ys < rh)
        border = inside & ((xs == 0) | (ys == 0) | (xs == rw - 1) | (ys == rh - 1))
        grid = jnp.where(border[..., None], jnp.asarray(WALL_CELL), jnp.asarray(EMPTY_CELL))
        zero = jnp.int32(0)
        doors = jnp.stack(
            [
                jnp.stack([G.randint(u[2], 2, rw - 2), zero]),  # (_rand_int(2, width - 2), 0)
                jnp.stack([G.randint(u[3], 2, rw - 2), rh - 1]),  # (.., height - 1)
                jnp.stack([zero, G.randint(u[4], 2, rh - 2)]),  # (0, _rand_int(2, height - 2))
                jnp.stack([rw - 1, G.randint(u[5], 2, rh - 2)]),  # (width - 1, ..)
            ]
        )
        # while len(doorColors) < 4: color = _rand_elem(COLOR_NAMES); if color in doorColors:
        # continue
        colours = _draw_distinct(u[6:10], NUM_COLOURS)
        for i in range(4):  # grid.set(*pos, Door(color))
            grid = G.put(grid, doors[i], G.cell(DOOR, colours[i], CLOSED))
        # place_agent(size=(width, height)): any cell inside the room's walls
        agent = jnp.stack([G.randint(u[10], 1, rw - 1), G.randint(u[11], 1, rh - 1)])
        direction = G.randint(u[12], 0, 4)
        target = G.randint(u[13], 0, 4)  # doorIdx = _rand_int(0, len(doorPos))
        extras = mission(DOOR, G.select(target, colours), G.select(target, doors))
        return self.init_state(grid, agent, direction, key, extras)


# ---------------------------------------------------------------- rooms with objects


class _ObjectRoom(MissionLevel):
    """A walled room with ``num_objs`` objects, then the agent, placed uniformly.

    Subclasses set the object types, whether a (type, colour) pair may repeat, and whether
    objects keep apart (PutNear's ``near_obj``).
    """

    num_objs: int = struct.field(pytree_node=False, default=2)

    TYPES = KEY_BALL_BOX
    DISTINCT = True  # "if (objType, objColor) in objs: continue"
    APART = False  # place_obj(obj, reject_fn=near_obj)
    MIN_OBJS = 1  # objs[self._rand_int(0, len(objs))] needs one object

    def __post_init__(self):
        pairs = len(self.TYPES) * NUM_COLOURS
        high, why = (pairs, "distinct (type, colour) pairs") if self.DISTINCT else (None, "")
        _check_int(self, "num_objs", self.MIN_OBJS, high, why or "the mission needs an object")
        super().__post_init__()

    def _fits(self, side: int) -> bool:
        """Whether every draw finds a cell in a ``side x side`` room (walls included)."""
        inner, n = side - 2, self.num_objs
        if inner * inner < n + 1:  # the objects, then the agent
            return False
        # near_obj blocks the 3 x 3 block around each object: the fewest objects that block
        # every cell of an a x b interior is ceil(a / 3) * ceil(b / 3) (the king graph's
        # domination number), so object k always finds a cell while k - 1 is below that
        return not self.APART or n <= ((inner + 2) // 3) ** 2

    def min_size(self):
        side = 3
        while not self._fits(side):
            side += 1
        why = f"{self.num_objs} objects" + (" apart from each other" if self.APART else "")
        return side, side, why + " and the agent inside the walls"

    def contents(self) -> Contents:
        names = {KEY: "key", BALL: "ball", BOX: "box"}
        return Contents(**{names[t]: ALL_COLOURS for t in self.TYPES})

    def objects(self, u: jax.Array):
        """Draw the walls and objects (``u``: uniforms ``(num_objs, 2)``).

        Returns ``(grid, kinds, colours, cells)``: the grid and int32 ``(num_objs,)``,
        ``(num_objs,)``, ``(num_objs, 2)`` in placement order.
        """
        w, h = self.width, self.height
        types = jnp.asarray(self.TYPES, jnp.int32)
        pairs = len(self.TYPES) * NUM_COLOURS
        if self.DISTINCT:  # redrawn while the (type, colour) pair is already placed
            pair = _draw_distinct(u[:, 0], pairs)
        else:  # objType = _rand_elem(types); objColor = _rand_elem(COLOR_NAMES)
            pair = G.randint(u[:, 0], 0, pairs)
        kinds = jax.vmap(G.select, in_axes=(0, None))(pair // NUM_COLOURS, types)
        colours = pair % NUM_COLOURS
        xs, ys = G.coords(w, h)

        def place(carry, xs_i):
            grid, near = carry
            u_i, kind, colour = xs_i
            # place_obj(obj[, reject_fn=near_obj]): an empty cell (not near an earlier object)
            cell = G.sample_cell(u_i, G.is_empty(grid) & ~near)
            grid = G.put(grid, cell, G.cell(kind, colour))
            if self.APART:  # near_obj: abs(dx) <= 1 and abs(dy) <= 1 for an earlier object
                near = near | ((jnp.abs(xs - cell[0]) <= 1) & (jnp.abs(ys - cell[1]) <= 1))
            return (grid, near), cell

        # grid.horz_wall(0, 0); ...; grid.vert_wall(width - 1, 0) (GoToObject: wall_rect)
        start = (jnp.asarray(G.room(w, h)), jnp.zeros((w, h), bool))
        (grid, _), cells = jax.lax.scan(place, start, (u[:, 1], kinds, colours))
        return grid, kinds, colours, cells

    def _layout(self, key: jax.Array, extra: int):
        """Objects, then ``place_agent()``; returns ``(grid, kinds, colours, cells, agent,
        direction, u)`` with ``extra`` more uniforms ``u``."""
        u_objects, u = jax.random.split(key)
        grid, kinds, colours, cells = self.objects(
            jax.random.uniform(u_objects, (self.num_objs, 2))
        )
        u = jax.random.uniform(u, (2 + extra,))
        agent = G.sample_cell(u[0], G.is_empty(grid))  # place_agent(): any empty cell
        return grid, kinds, colours, cells, agent, G.randint(u[1], 0, 4), u[2:]


class GoToObject(_ObjectRoom, _GoTo):
    """``GoToObjectEnv``: a room with ``num_objs`` keys, balls and boxes of distinct (type,
    colour) pairs; go next to the one the mission names and perform ``done``.

    Each object's (type, colour) is uniform among the pairs not placed yet, its cell uniform
    among the empty ones; the agent stands on a uniform empty cell with a uniform direction;
    the target is uniform among the objects. ``state.extras`` is a
    :class:`~jaxgrid.levels.keys.Mission` (its type, colour and cell, ``target_pos``).

    Step (``GoToObjectEnv.step``): ``toggle`` terminates (an opened box vanishes first);
    ``done`` terminates, with the success reward when the agent is next to the target's
    starting cell (``target_pos``), whatever lies there now (the target may have been picked
    up and carried off). MiniGrid builds square sizes only, with ``see_through_walls=True``;
    here width and height are each at least the smallest square side that holds the objects
    and the agent (4 for up to 3 objects). With three objects or more, two may shut the agent
    into a corner away from the target, in MiniGrid's layouts and here alike.
    """

    def mission(self, state: State) -> jax.Array:
        task = state.extras
        return mission_words.fill("go to the {colour} {kind}", colour=task.colour, kind=task.kind)

    def generate(self, key: jax.Array) -> State:
        grid, kinds, colours, cells, agent, direction, u = self._layout(key, 1)
        target = G.randint(u[0], 0, self.num_objs)  # objIdx = _rand_int(0, len(objs))
        pick = lambda a: G.select(target, a)
        extras = mission(pick(kinds), pick(colours), pick(cells))
        return self.init_state(grid, agent, direction, key, extras)


class Fetch(_ObjectRoom):
    """``FetchEnv``: a room with ``num_objs`` keys and balls; pick up one of the type and colour
    the mission names.

    Each object is a uniform (type, colour) pair among keys and balls of the six colours, the
    same pair possibly more than once; its cell is uniform among the empty ones; the agent
    stands on a uniform empty cell with a uniform direction; the mission names the type and
    colour of a uniform object, in one of five uniform phrasings. ``state.extras`` is a
    :class:`FetchMission`: that type and colour, the cell of the object drawn (after a
    conversion, the first cell in MiniGrid's grid order holding such an object, ``(-1, -1)``
    if none) and the phrasing.

    Step (``FetchEnv.step``): after any step that leaves the agent carrying something, the
    episode terminates, with the success reward if the carried object's type and colour are
    the mission's (any copy counts), else reward 0. MiniGrid builds square sizes only, with
    ``see_through_walls=True``; here width and height are each at least the smallest square
    side that holds the objects and the agent. With three objects or more, two may shut the
    agent into a corner away from the target, in MiniGrid's layouts and here alike (3 or 4
    resets in 10,000 of ``MiniGrid-Fetch-8x8-N3-v0``).
    """

    num_objs: int = struct.field(pytree_node=False, default=3)

    TYPES = KEY_BALL
    DISTINCT = False

    def rule(self, before, after, action, reward, terminated):
        # if self.carrying: if <same color and type as the target>: reward = self._reward();
        # terminated = True; else: reward = 0; terminated = True
        carried, m = after.carrying.astype(jnp.int32), after.extras
        holding = carried[0] != EMPTY
        match = (carried[0] == m.kind) & (carried[1] == m.colour)
        reward = jnp.where(holding, jnp.where(match, self.success_reward(after), 0.0), reward)
        return reward, terminated | holding

    def mission(self, state: State) -> jax.Array:
        task = state.extras
        slots = dict(colour=task.colour, kind=task.kind)
        phrased = [
            mission_words.fill(f"{lead} {{colour}} {{kind}}", **slots) for lead in FETCH_PHRASINGS
        ]
        return mission_words.choose(task.phrasing, phrased)

    def generate(self, key: jax.Array) -> State:
        grid, kinds, colours, cells, agent, direction, u = self._layout(key, 2)
        target = G.randint(u[0], 0, self.num_objs)  # objs[self._rand_int(0, len(objs))]
        pick = lambda a: G.select(target, a)
        phrasing = G.randint(u[1], 0, len(FETCH_PHRASINGS))  # idx = self._rand_int(0, 5)
        target = mission(pick(kinds), pick(colours), pick(cells))
        extras = FetchMission(**vars(target), phrasing=phrasing.astype(jnp.int32))
        return self.init_state(grid, agent, direction, key, extras)


class PutNear(_ObjectRoom):
    """``PutNearEnv``: a room with ``num_objs`` keys, balls and boxes of distinct (type, colour)
    pairs, none next to another (diagonals included); put the object the mission names next to
    the other one it names.

    Each object's (type, colour) is uniform among the pairs not placed yet, its cell uniform
    among the empty cells at Chebyshev distance 2 or more from the objects placed before; the
    agent stands on a uniform empty cell with a uniform direction; the object to move is
    uniform among the objects, the target uniform among the others. ``state.extras`` is a
    :class:`PutNearMission`.

    Step (``PutNearEnv.step``): a ``pickup`` that leaves the agent carrying an object whose
    type or colour differs from the one to move terminates (reward 0); a ``drop`` while
    carrying something terminates, with the success reward if the object was put down (the
    cell faced was empty) within one cell of the target's starting cell (``target_pos``,
    diagonals included), whatever object it is. MiniGrid builds square sizes only, with
    ``see_through_walls=True``; here width and height are each at least the smallest square
    side in which every draw finds a cell (6 for 2 to 4 objects: MiniGrid may loop forever
    in smaller ones).
    """

    APART = True
    MIN_OBJS = 2  # the target is drawn among the other objects

    def rule(self, before, after, action, reward, terminated):
        carried, m = after.carrying.astype(jnp.int32), after.extras
        # if action == pickup and self.carrying: if <type or color differ from the move
        # object's>: terminated = True
        wrong = (action == PICKUP) & (carried[0] != EMPTY)
        wrong = wrong & ((carried[0] != m.move.kind) | (carried[1] != m.move.colour))
        # if action == drop and preCarrying: if self.grid.get(ox, oy) is preCarrying: ...;
        # terminated = True. The carried object is in the cell faced iff it was put down.
        dropping = (action == DROP) & (before.carrying[0] != EMPTY)
        put_down = dropping & (after.carrying[0] == EMPTY)
        # if abs(ox - tx) <= 1 and abs(oy - ty) <= 1: reward = self._reward()
        near = jnp.max(jnp.abs(front_pos(after) - m.target.pos)) <= 1
        reward = jnp.where(put_down & near, self.success_reward(after), reward)
        return reward, terminated | wrong | dropping

    def mission(self, state: State) -> jax.Array:
        move, target = state.extras.move, state.extras.target
        return mission_words.fill(
            "put the {move_colour} {move_kind} near the {target_colour} {target_kind}",
            move_colour=move.colour,
            move_kind=move.kind,
            target_colour=target.colour,
            target_kind=target.kind,
        )

    def generate(self, key: jax.Array) -> State:
        grid, kinds, colours, cells, agent, direction, u = self._layout(key, 2)
        n = self.num_objs
        move = G.randint(u[0], 0, n)  # objIdx = _rand_int(0, len(objs))
        # while True: targetIdx = _rand_int(0, len(objs)); if targetIdx != objIdx: break
        other = G.randint(u[1], 0, n - 1)
        target = other + (other >= move)
        about = lambda i: mission(G.select(i, kinds), G.select(i, colours), G.select(i, cells))
        extras = PutNearMission(move=about(move), target=about(target))
        return self.init_state(grid, agent, direction, key, extras)


# ------------------------------------------------------------------------------------ ids


def _go_to_door(size: int) -> Callable[[], Environment]:
    # GoToDoorEnv(size): max_steps 4 * size**2, see_through_walls=True.
    return lambda: GoToDoor(width=size, height=size, max_steps=4 * size**2, see_through_walls=True)


def _objects(cls, size: int, n: int, max_steps: int) -> Callable[[], Environment]:
    # see_through_walls=True for the three
    return lambda: cls(
        width=size, height=size, max_steps=max_steps, see_through_walls=True, num_objs=n
    )


IDS: dict[str, Callable[[], Environment]] = {
    **{f"MiniGrid-GoToDoor-{n}x{n}-v0": _go_to_door(n) for n in (5, 6, 8)},
    # GoToObjectEnv(size, numObjs) and FetchEnv(size, numObjs): max_steps 5 * size**2
    **{
        f"MiniGrid-GoToObject-{s}x{s}-N{n}-v0": _objects(GoToObject, s, n, 5 * s**2)
        for s, n in ((6, 2), (8, 2))
    },
    **{
        f"MiniGrid-Fetch-{s}x{s}-N{n}-v0": _objects(Fetch, s, n, 5 * s**2)
        for s, n in ((5, 2), (6, 2), (8, 3))
    },
    # PutNearEnv(size, numObjs): max_steps 5 * size
    **{
        f"MiniGrid-PutNear-{s}x{s}-N{n}-v0": _objects(PutNear, s, n, 5 * s)
        for s, n in ((6, 2), (8, 3))
    },
}
