"""MiniGrid's key-and-locked-door levels, generated natively, with their own success rules.

One thing, the RoomGrid key-and-door family of MiniGrid, each a faithful generator, hence
its length.

``Unlock``, ``UnlockPickup``, ``BlockedUnlockPickup`` and ``KeyCorridor`` are built by
MiniGrid's ``RoomGrid`` (a lattice of square rooms sharing walls). Each ``generate`` mirrors
the level's ``_gen_grid`` and the ``RoomGrid`` helpers it calls; the comments quote the
MiniGrid call each line reproduces. These levels override ``MiniGridEnv.step``: the episode
succeeds (reward ``1 - 0.9 * step_count / max_steps``, terminated) when the agent opens the
door (Unlock) or picks up the target object (the others). The task object is kept in
``state.extras`` as a :class:`Mission`.

Where MiniGrid rejection-samples a uniform proposal (``place_obj``, ``place_agent``,
``connect_all``'s door proposals) we sample uniformly among the proposals it would accept,
which is the distribution rejection sampling converges to, with no retry loop and no cap.
MiniGrid gives up (raises) after 1000 (``place_obj``) or 5000 (``connect_all``) proposals;
at the registered sizes that happens with probability below ``1e-50``, so the distributions
agree; on much larger custom corridors MiniGrid may raise where a layout is returned here.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import grid as G
from jaxgrid import mission as mission_words
from jaxgrid.constants import (
    BALL,
    BOX,
    CLOSED,
    DIR_TO_VEC,
    DOOR,
    EMPTY,
    EMPTY_CELL,
    KEY,
    LOCKED,
    OPEN,
    PICKUP,
    TOGGLE,
    WALL,
    WALL_CELL,
)
from jaxgrid.contents import ALL_COLOURS, Contents
from jaxgrid.dynamics import get_cell, transition
from jaxgrid.environment import Environment, check_action
from jaxgrid.types import State, TimeStep

NUM_COLOURS = 6  # MiniGrid's COLOR_NAMES: _rand_color() is uniform over all six


@struct.dataclass
class Mission:
    """The episode's task object (MiniGrid's ``self.door`` for Unlock, else ``self.obj``).

    ``kind`` and ``colour`` are int32 MiniGrid indices; ``pos`` is int32 ``(2,)``, the cell it
    was placed on (``(-1, -1)`` if it was carried when a MiniGrid env was converted). The
    pickup levels hold one object of the target's kind, so "carrying an object of this kind
    and colour" is MiniGrid's identity test ``self.carrying == self.obj``.
    """

    kind: jax.Array
    colour: jax.Array
    pos: jax.Array


def mission(kind, colour, pos) -> Mission:
    """A :class:`Mission` with int32 leaves (arguments may be traced)."""
    return Mission(
        kind=jnp.asarray(kind, jnp.int32),
        colour=jnp.asarray(colour, jnp.int32),
        pos=jnp.asarray(pos, jnp.int32),
    )


# --------------------------------------------------------------------------- RoomGrid


def roomgrid_size(room_size: int, num_rows: int, num_cols: int) -> tuple[int, int]:
    """``(width, height)`` of a ``RoomGrid``: rooms of ``room_size`` cells share their walls."""
    return (room_size - 1) * num_cols + 1, (room_size - 1) * num_rows + 1


def _rooms(width: int, height: int, room_size: int) -> np.ndarray:
    """Every room's walls (``grid.wall_rect(*room.top, *room.size)`` for each room)."""
    grid = np.broadcast_to(EMPTY_CELL, (width, height, 3)).copy()
    xs, ys = G.coords(width, height)
    grid[(xs % (room_size - 1) == 0) | (ys % (room_size - 1) == 0)] = WALL_CELL
    return grid


def _walls(room_size: int, num_rows: int, num_cols: int):
    """The walls between neighbouring rooms, in a fixed order: right walls, then bottom walls.

    Returns ``(base, axis, rooms)``: a wall's door cell is ``base + offset * axis`` with
    ``offset`` drawn from ``1 .. room_size - 2``; ``rooms`` holds the two room indices
    ``j * num_cols + i`` the wall separates.
    """
    s = room_size - 1
    base, axis, rooms = [], [], []
    for j in range(num_rows):  # room.door_pos[0] = (x_m, _rand_int(y_l, y_m))
        for i in range(num_cols - 1):
            base.append(((i + 1) * s, j * s))
            axis.append((0, 1))
            rooms.append((j * num_cols + i, j * num_cols + i + 1))
    for j in range(num_rows - 1):  # room.door_pos[1] = (_rand_int(x_l, x_m), y_m)
        for i in range(num_cols):
            base.append((i * s, (j + 1) * s))
            axis.append((1, 0))
            rooms.append((j * num_cols + i, (j + 1) * num_cols + i))
    as_array = lambda a: np.array(a, np.int32).reshape(-1, 2)
    return as_array(base), as_array(axis), as_array(rooms)


def _wall_cells(width: int, height: int, room_size: int, base, axis):
    """Static maps of the walls' door cells: ``which`` int32 ``(W, H, walls)`` one-hot (all
    zero off the walls' inner cells) and ``along`` int32 ``(W, H)``, the cell's offset along
    its wall (-1 elsewhere)."""
    which = np.zeros((width, height, len(base)), np.int32)
    along = np.full((width, height), -1, np.int32)
    for w, (b, a) in enumerate(zip(base, axis, strict=True)):
        for k in range(1, room_size - 1):
            x, y = b + k * a
            which[x, y, w], along[x, y] = 1, k
    return which, along


def _start_pos(room_size: int, num_rows: int, num_cols: int) -> np.ndarray:
    """Where ``RoomGrid._gen_grid`` leaves the agent until ``place_agent`` moves it."""
    # self.agent_pos = ((num_cols // 2) * (room_size - 1) + room_size // 2, ...)
    s = room_size - 1
    return np.array(
        [(num_cols // 2) * s + room_size // 2, (num_rows // 2) * s + room_size // 2], np.int32
    )


def _in_room(shape, room_size: int, i, j) -> jax.Array:
    """bool ``(W, H)``: the rectangle ``room.top, room.size`` of room ``(i, j)``, walls included."""
    xs, ys = G.coords(*shape)
    s = room_size - 1
    return (xs >= i * s) & (xs <= (i + 1) * s) & (ys >= j * s) & (ys <= (j + 1) * s)


def place_in_room(u, grid, room_size: int, i, j, agent_pos) -> jax.Array:
    """``RoomGrid.place_in_room``: a uniform empty cell of room ``(i, j)`` that is neither the
    agent's cell nor next to it (``reject_next_to``: Manhattan distance below 2)."""
    xs, ys = G.coords(*grid.shape[:2])
    near = np.abs(xs - agent_pos[0]) + np.abs(ys - agent_pos[1]) < 2
    allowed = G.is_empty(grid) & _in_room(grid.shape[:2], room_size, i, j) & ~near
    return G.sample_cell(u, allowed)


def place_agent(u, grid, room_size: int, i, j) -> tuple[jax.Array, jax.Array]:
    """``RoomGrid.place_agent(i, j)``: ``(pos, dir)`` uniform over the empty cells of the room
    and the four directions, keeping only poses whose front cell is empty or a wall.

    MiniGrid redraws cell and direction together until the front cell passes, which is the
    uniform distribution over the passing ``(cell, direction)`` pairs sampled here.
    """
    width, height = grid.shape[:2]
    kind = grid[..., 0]
    ok = (kind == EMPTY) | (kind == WALL)  # front_cell is None or front_cell.type == "wall"
    # front[x, y, d] = ok[(x, y) + DIR_TO_VEC[d]]; the wrap-around only touches border cells,
    # which are walls and never candidates.
    front = jnp.stack([jnp.roll(ok, (-dx, -dy), axis=(0, 1)) for dx, dy in DIR_TO_VEC], -1)
    room = G.is_empty(grid) & _in_room((width, height), room_size, i, j)
    xd = G.sample_cell(u, (room[..., None] & front).reshape(width, height * 4))
    return jnp.stack([xd[0], xd[1] // 4]), xd[1] % 4


def _pick(u, allowed) -> jax.Array:
    """Index of a uniform ``True`` entry of the 1-D bool ``allowed`` (not all False)."""
    cum = jnp.cumsum(allowed.astype(jnp.int32))
    r = jnp.minimum(jnp.floor(u * cum[-1]).astype(jnp.int32), cum[-1] - 1)
    return jnp.argmax(cum > r)


def _door(colour, state) -> jax.Array:
    return G.cell(DOOR, colour, state)


# ----------------------------------------------------------------------------- levels


class RoomLevel(Environment):
    """A ``RoomGrid`` level with a success rule; ``step`` is ``MiniGridEnv.step`` plus it.

    ``width`` and ``height`` must equal ``roomgrid_size(room_size, rows, cols)`` (checked at
    construction). Subclasses implement :meth:`succeeded`.
    """

    room_size: int = struct.field(pytree_node=False, default=6)

    NUM_ROWS = 1
    NUM_COLS = 2
    MIN_ROOM_SIZE = 4  # the agent's room holds the key, the agent and (Blocked) the ball

    def rows_cols(self) -> tuple[int, int]:
        return self.NUM_ROWS, self.NUM_COLS

    def mission(self, state: State) -> jax.Array:
        # f"pick up the {obj.color} {obj.type}"
        task = state.extras
        return mission_words.fill("pick up the {colour} {kind}", colour=task.colour, kind=task.kind)

    def __post_init__(self):
        name = type(self).__name__
        s = self.room_size
        if not isinstance(s, int) or isinstance(s, bool) or s < self.MIN_ROOM_SIZE:
            raise ValueError(
                f"{name}.room_size must be an int >= {self.MIN_ROOM_SIZE} (rooms must fit "
                f"the level's objects and the agent), got {s!r}"
            )
        self._check_rows_cols()
        rows, cols = self.rows_cols()
        width, height = roomgrid_size(s, rows, cols)
        for field, want in (("width", width), ("height", height)):
            if getattr(self, field) != want:
                raise ValueError(
                    f"{name}.{field} must be {want} for room_size={s} ({rows} x {cols} rooms "
                    f"sharing walls), got {getattr(self, field)!r}"
                )
        super().__post_init__()

    def _check_rows_cols(self) -> None:
        pass

    def min_size(self):
        rows, cols = self.rows_cols()
        width, height = roomgrid_size(self.room_size, rows, cols)
        return width, height, f"{rows} x {cols} rooms of room_size={self.room_size}"

    def succeeded(self, state: State, action: jax.Array) -> jax.Array:
        """Whether the step that produced ``state`` with ``action`` completes the mission."""
        raise NotImplementedError

    def core_step(self, state: State, action: jax.Array):
        """``MiniGridEnv.step`` without the level's rule: ``(state, reward, terminated,
        truncated)`` of :func:`~jaxgrid.dynamics.transition`."""
        return transition(state, action, self.max_steps)

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """``MiniGridEnv.step``, then the level's rule: on success ``reward = self._reward()``
        (``1 - 0.9 * step_count / max_steps``) and ``terminated = True``."""
        check_action(action)
        action = jnp.asarray(action, jnp.int32)
        state, reward, terminated, truncated = self.core_step(state, action)
        success = self.succeeded(state, action)
        success_reward = 1.0 - 0.9 * (state.step_count.astype(jnp.float32) / self.max_steps)
        reward = jnp.where(success, success_reward, reward).astype(jnp.float32)
        return state, self.make_timestep(state, reward, terminated | success, truncated)

    def _picked_up_target(self, state: State, action: jax.Array) -> jax.Array:
        # if action == self.actions.pickup: if self.carrying and self.carrying == self.obj:
        m = state.extras
        carried = state.carrying.astype(jnp.int32)
        return (action == PICKUP) & (carried[0] == m.kind) & (carried[1] == m.colour)

    def _two_rooms(self, key: jax.Array, n: int):
        """``RoomGrid._gen_grid`` for one row of two rooms: walls, the door cell of the wall
        between them, uniforms for the rest, and the agent's provisional cell."""
        u = jax.random.uniform(key, (n + 1,))
        s = self.room_size
        grid = jnp.asarray(_rooms(self.width, self.height, s))
        # room.door_pos[0] = (x_m, _rand_int(y_l, y_m))
        door = jnp.stack([jnp.int32(s - 1), G.randint(u[n], 1, s - 1)])
        return grid, door, u[:n], _start_pos(s, 1, 2)


class Unlock(RoomLevel):
    """``UnlockEnv``: open the locked door between two rooms; its key is in the agent's room.

    Success: any ``toggle`` after which the door is open (MiniGrid tests ``self.door.is_open``
    after every toggle, wherever the agent faces). Defaults (``MiniGrid-Unlock-v0``): 11 x 6,
    ``room_size`` 6 (MiniGrid's only one; 4 or more is accepted), ``max_steps`` 288.
    Placements sample uniformly among the cells ``place_obj``/``place_agent`` would accept.
    """

    MISSION = "open the door"
    CONTENTS = Contents(door=ALL_COLOURS, key=ALL_COLOURS)

    def mission(self, state: State) -> jax.Array:
        return mission_words.fill(self.MISSION)

    def succeeded(self, state: State, action: jax.Array) -> jax.Array:
        # if action == self.actions.toggle: if self.door.is_open:
        door = get_cell(state.grid, state.extras.pos)
        return (action == TOGGLE) & (door[0] == DOOR) & (door[2] == OPEN)

    def generate(self, key: jax.Array) -> State:
        grid, door, u, mid = self._two_rooms(key, 4)
        s = self.room_size
        colour = G.randint(u[0], 0, NUM_COLOURS)  # add_door(0, 0, 0, locked=True): _rand_color()
        grid = G.put(grid, door, _door(colour, LOCKED))
        key_pos = place_in_room(u[1], grid, s, 0, 0, mid)  # add_object(0, 0, "key", door.color)
        grid = G.put(grid, key_pos, G.cell(KEY, colour))
        agent, direction = place_agent(u[2], grid, s, 0, 0)  # place_agent(0, 0)
        return self.init_state(grid, agent, direction, key, mission(DOOR, colour, door))


class UnlockPickup(RoomLevel):
    """``UnlockPickupEnv``: unlock the door, then pick up the box in the other room.

    Success: any ``pickup`` after which the box is in the agent's hands. Defaults
    (``MiniGrid-UnlockPickup-v0``): 11 x 6, ``room_size`` 6 (4 or more is accepted),
    ``max_steps`` 288. Placements sample uniformly among the cells ``place_obj``/
    ``place_agent`` would accept: the box is never within one step of the agent's provisional
    cell ((8, 3) at room_size 6), as MiniGrid's ``reject_next_to`` requires.
    """

    BLOCKED = False
    CONTENTS = Contents(door=ALL_COLOURS, key=ALL_COLOURS, box=ALL_COLOURS)

    def succeeded(self, state: State, action: jax.Array) -> jax.Array:
        return self._picked_up_target(state, action)

    def generate(self, key: jax.Array) -> State:
        grid, door, u, mid = self._two_rooms(key, 6)
        s = self.room_size
        box_colour = G.randint(u[0], 0, NUM_COLOURS)  # add_object(1, 0, kind="box")
        box = place_in_room(u[1], grid, s, 1, 0, mid)
        grid = G.put(grid, box, G.cell(BOX, box_colour))
        colour = G.randint(u[2], 0, NUM_COLOURS)  # add_door(0, 0, 0, locked=True)
        grid = G.put(grid, door, _door(colour, LOCKED))
        if self.BLOCKED:  # self.grid.set(pos[0] - 1, pos[1], Ball(self._rand_color()))
            ball = G.cell(BALL, G.randint(u[5], 0, NUM_COLOURS))
            grid = G.put(grid, door - jnp.array([1, 0]), ball)
        key_pos = place_in_room(u[3], grid, s, 0, 0, mid)  # add_object(0, 0, "key", door.color)
        grid = G.put(grid, key_pos, G.cell(KEY, colour))
        agent, direction = place_agent(u[4], grid, s, 0, 0)  # place_agent(0, 0)
        return self.init_state(grid, agent, direction, key, mission(BOX, box_colour, box))


class BlockedUnlockPickup(UnlockPickup):
    """``BlockedUnlockPickupEnv``: UnlockPickup with a ball of a random colour in front of the
    door, on the agent's side, to be moved first.

    Success: any ``pickup`` after which the box is in the agent's hands. Defaults
    (``MiniGrid-BlockedUnlockPickup-v0``): 11 x 6, ``room_size`` 6, ``max_steps`` 576.
    Placements as in :class:`UnlockPickup`.
    """

    BLOCKED = True
    CONTENTS = Contents(door=ALL_COLOURS, key=ALL_COLOURS, box=ALL_COLOURS, ball=ALL_COLOURS)


class KeyCorridor(RoomLevel):
    """``KeyCorridorEnv``: a corridor of rooms in the middle column; a ball behind a locked door
    in the right column; its key in a random room of the left column.

    Success: any ``pickup`` after which the ball is in the agent's hands.
    ``MiniGrid-KeyCorridorSxRy`` is ``room_size=x, num_rows=y, num_cols=3``, ``max_steps``
    ``30 * room_size**2``; like ``KeyCorridorEnv`` any ``num_cols >= 3`` is accepted, except
    where MiniGrid cannot build a layout (``num_cols > 3`` with one row; ``room_size`` 3 with 4
    or 5 columns), which raises ``ValueError``.
    Placements sample uniformly among the cells ``place_obj``/``place_agent`` would accept.
    ``connect_all`` proposes a random (room, wall) and keeps it if the wall has no door yet and
    neither room is the locked one, until every room is reachable from the agent's; each wall
    has two proposals (one per side), so each kept proposal is a uniform choice among the
    acceptable walls, which is how it is drawn here, in a loop of at most one step per wall.
    """

    num_rows: int = struct.field(pytree_node=False, default=3)
    num_cols: int = struct.field(pytree_node=False, default=3)

    CONTENTS = Contents(door=ALL_COLOURS, key=ALL_COLOURS, ball=ALL_COLOURS)
    MIN_ROOM_SIZE = 3  # RoomGrid's minimum: each room keeps one interior cell

    def rows_cols(self) -> tuple[int, int]:
        return self.num_rows, self.num_cols

    def _check_rows_cols(self) -> None:
        name = type(self).__name__
        for field, low, why in (
            ("num_rows", 1, "one row of rooms at least"),
            ("num_cols", 3, "the key's column, the corridor and the locked rooms' column"),
        ):
            value = getattr(self, field)
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"{name}.{field} must be an int >= {low} ({why}), got {value!r}")
        # Layouts MiniGrid cannot build (connect_all or place_obj never succeeds): refused here
        # rather than returned with a room cut off or the ball on the outer wall.
        if self.num_cols > 3 and self.num_rows < 2:
            raise ValueError(
                f"{name}.num_rows must be at least 2 when num_cols > 3 (the rooms right of the "
                f"locked room are reached around it, through another row), got {self.num_rows}"
            )
        if self.num_cols // 2 == 2 and self.room_size < 4:
            raise ValueError(
                f"{name}.room_size must be at least 4 when num_cols is {self.num_cols} (the "
                "agent's provisional cell is then the only cell of the ball's room), got "
                f"{self.room_size}"
            )

    def succeeded(self, state: State, action: jax.Array) -> jax.Array:
        return self._picked_up_target(state, action)

    def generate(self, key: jax.Array) -> State:
        s, rows, cols = self.room_size, self.num_rows, self.num_cols
        base, axis, rooms = _walls(s, rows, cols)
        n_walls, n_rooms = len(base), rows * cols
        n_right = rows * (cols - 1)
        u = jax.random.uniform(key, (3 + n_walls, 3))  # one draw: rows 3.. are per wall
        # RoomGrid._gen_grid: room walls, one door cell drawn per wall, agent in the middle
        grid = _rooms(self.width, self.height, s)
        offsets = G.randint(u[3:, 0], 1, s - 1)
        door_pos = jnp.asarray(base) + offsets[:, None] * jnp.asarray(axis)
        mid = _start_pos(s, rows, cols)
        # for j in range(1, num_rows): self.remove_wall(1, j, 3)
        corridor = np.zeros(n_walls, bool)
        for j in range(1, rows):
            grid[s : 2 * s - 2, j * (s - 1)] = EMPTY_CELL  # the top wall of room (1, j)
            corridor[n_right + (j - 1) * cols + 1] = True
        grid = jnp.asarray(grid)
        # room_idx = _rand_int(0, num_rows); add_door(2, room_idx, 2, locked=True)
        row = G.randint(u[0, 0], 0, rows)
        locked_wall = row * (cols - 1) + 1  # the right wall of room (1, room_idx)
        colour = G.randint(u[0, 1], 0, NUM_COLOURS)
        locked_pos = door_pos[locked_wall]
        grid = G.put(grid, locked_pos, _door(colour, LOCKED))
        # add_object(2, room_idx, kind=self.obj_type)
        ball_colour = G.randint(u[0, 2], 0, NUM_COLOURS)
        ball = place_in_room(u[1, 0], grid, s, 2, row, mid)
        grid = G.put(grid, ball, G.cell(BALL, ball_colour))
        # add_object(0, _rand_int(0, num_rows), "key", door.color)
        key_pos = place_in_room(u[1, 2], grid, s, 0, G.randint(u[1, 1], 0, rows), mid)
        grid = G.put(grid, key_pos, G.cell(KEY, colour))
        # place_agent(1, num_rows // 2)
        agent, direction = place_agent(u[2, 0], grid, s, 1, rows // 2)

        # connect_all(): doors of uniform colours until every room is reachable. Rooms carry
        # component labels: joining two components relabels one, so "every room reachable
        # from the agent's" is "one label", tested in O(rooms) per door.
        def join(labels, a, b):  # labels[a], labels[b] as select-sums: no gather under vmap
            return jnp.where(labels == G.select(b, labels), G.select(a, labels), labels)

        labels = jnp.arange(n_rooms)
        for w in np.flatnonzero(corridor):  # the corridor's removed walls (static)
            labels = join(labels, *rooms[w])
        labels = join(labels, row * cols + 1, row * cols + 2)  # through the locked door
        connected = jnp.asarray(corridor) | (jnp.arange(n_walls) == locked_wall)
        locked_room = row * cols + 2
        acceptable_rooms = (rooms[:, 0] != locked_room) & (rooms[:, 1] != locked_room)
        start = (rows // 2) * cols + 1

        def add_door(carry, u_t):
            connected, labels, added, colours = carry
            wall = _pick(u_t[1], ~connected & acceptable_rooms)
            # if len(reach) == self.num_rows * self.num_cols: break
            add = ~jnp.all(labels == labels[start])
            new = (jnp.arange(n_walls) == wall) & add
            ends = jnp.sum(jnp.where(new[:, None], rooms, 0), axis=0)
            labels = jnp.where(add, join(labels, ends[0], ends[1]), labels)
            colour_t = G.randint(u_t[2], 0, NUM_COLOURS)  # _rand_elem(door_colors)
            return (connected | new, labels, added | new, jnp.where(new, colour_t, colours)), None

        none = jnp.zeros(n_walls, bool)
        carry = (connected, labels, none, jnp.zeros(n_walls, jnp.int32))
        (_, _, added, colours), _ = jax.lax.scan(add_door, carry, u[3:])  # a step per wall
        # paint the added doors: each wall cell reads its wall's (added, offset, colour) through
        # a static one-hot matrix, one small matmul rather than a (walls, W, H) select
        which, along = _wall_cells(self.width, self.height, s, base, axis)
        per_wall = jnp.stack([added.astype(jnp.int32), offsets, colours], axis=1)
        added_c, offset_c, colour_c = jnp.moveaxis(jnp.asarray(which) @ per_wall, -1, 0)
        here = (added_c == 1) & (offset_c == jnp.asarray(along))
        door = jnp.stack(
            [jnp.full_like(colour_c, DOOR), colour_c, jnp.full_like(colour_c, CLOSED)], -1
        )
        grid = jnp.where(here[..., None], door.astype(jnp.uint8), grid)
        return self.init_state(grid, agent, direction, key, mission(BALL, ball_colour, ball))


# ----------------------------------------------------------------------------- ids


def _unlock(cls, factor: int):
    # max_steps = factor * room_size**2 with room_size 6; RoomGrid: see_through_walls=False.
    return lambda: cls(width=11, height=6, max_steps=factor * 36)


def _keycorridor(room_size: int, num_rows: int):
    # KeyCorridorEnv(room_size, num_rows): max_steps = 30 * room_size**2, num_cols 3.
    width, height = roomgrid_size(room_size, num_rows, 3)
    return lambda: KeyCorridor(
        width=width,
        height=height,
        max_steps=30 * room_size**2,
        room_size=room_size,
        num_rows=num_rows,
    )


IDS = {
    "MiniGrid-Unlock-v0": _unlock(Unlock, 8),
    "MiniGrid-UnlockPickup-v0": _unlock(UnlockPickup, 8),
    "MiniGrid-BlockedUnlockPickup-v0": _unlock(BlockedUnlockPickup, 16),
    **{
        f"MiniGrid-KeyCorridorS{s}R{r}-v0": _keycorridor(s, r)
        for s, r in ((3, 1), (3, 2), (3, 3), (4, 3), (5, 3), (6, 3))
    },
}
