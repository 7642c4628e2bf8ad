"""MiniGrid's ObstructedMaze levels, generated natively, with boxes that hold keys.

Rooms of 6 cells share walls (MiniGrid's ``RoomGrid``); locked doors have their keys in a
room on the agent's side, hidden in grey boxes (``h``), and green balls block the doors
(``b``). The agent must pick up the blue ball. ``generate`` mirrors ``_gen_grid`` of
``ObstructedMaze_1Dlhb``, ``ObstructedMaze_Full`` and ``ObstructedMaze_Full_V1``; the comments
quote the MiniGrid call each line reproduces. Placements sample uniformly among the cells
``place_obj``/``place_agent`` would accept (the distribution their rejection sampling
converges to, no retry loop). Like MiniGrid's v0 levels, a blocking ball placed after a key
may cover it (the layout is then unsolvable); the v1 levels add the keys after every door.

A box's contents are not part of MiniGrid's cell encoding, so they live in ``state.extras``
(:class:`HiddenKeys`): the object inside the box on each cell, and inside the carried box.
``step`` is ``MiniGridEnv.step`` with ``Box.toggle`` putting the contents on the box's cell,
and the contents moving with a box that is picked up or dropped; success (reward
``1 - 0.9 * step_count / max_steps``, terminated) is any ``pickup`` after which the blue ball
is in the agent's hands.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import grid as G
from jaxgrid.constants import (
    BALL,
    BOX,
    CLOSED,
    COLOR_TO_IDX,
    DIR_TO_VEC,
    DOOR,
    DROP,
    EMPTY,
    EMPTY_CELL,
    KEY,
    LOCKED,
    PICKUP,
    TOGGLE,
)
from jaxgrid.contents import ALL_COLOURS, Contents
from jaxgrid.dynamics import front_pos, get_cell, set_cell, transition
from jaxgrid.levels.keys import (
    Mission,
    RoomLevel,
    _rooms,
    _start_pos,
    _walls,
    place_agent,
    place_in_room,
    roomgrid_size,
)
from jaxgrid.types import State

ROOM_SIZE = 6  # ObstructedMazeEnv: room_size = 6, fixed
# MiniGrid's COLOR_NAMES is sorted by name: ["blue", "green", "grey", "purple", "red", "yellow"]
TARGET = COLOR_TO_IDX["blue"]  # ball_to_find_color = COLOR_NAMES[0]
BLOCKING = COLOR_TO_IDX["green"]  # blocking_ball_color = COLOR_NAMES[1]
BOX_COLOUR = COLOR_TO_IDX["grey"]  # box_color = COLOR_NAMES[2]
SIDE_ROOMS = ((2, 1), (1, 2), (0, 1), (1, 0))  # ObstructedMaze_Full: side_rooms
CORNERS = ((2, 0), (2, 2), (0, 2), (0, 0))  # and corners, in MiniGrid's order


@struct.dataclass
class HiddenKeys(Mission):
    """ObstructedMaze's task (the blue ball, as :class:`~jaxgrid.levels.keys.Mission`) and what
    the boxes hold: ``contents`` uint8 ``(W, H, 3)``, the encoding of the object inside the box
    on each cell (``EMPTY_CELL`` where there is no box or it is empty), and ``carried`` uint8
    ``(3,)``, the contents of the box in the agent's hands."""

    contents: jax.Array
    carried: jax.Array


class _ObstructedMaze(RoomLevel):
    """What the ObstructedMaze levels share: fixed room size, boxes with contents, success."""

    key_in_box: bool = struct.field(pytree_node=False, default=True)
    blocked: bool = struct.field(pytree_node=False, default=True)

    MIN_ROOM_SIZE = ROOM_SIZE

    def _check_rows_cols(self) -> None:
        name = type(self).__name__
        if self.room_size != ROOM_SIZE:
            raise ValueError(
                f"{name}.room_size must be {ROOM_SIZE} (MiniGrid's ObstructedMazeEnv fixes it), "
                f"got {self.room_size!r}"
            )

    def contents(self) -> Contents:
        balls = {"blue", "green"} if self.blocked else {"blue"}  # the target, blocking balls
        boxes = {"grey"} if self.key_in_box else ()
        return Contents(door=ALL_COLOURS, key=ALL_COLOURS, ball=balls, box=boxes)

    def succeeded(self, state: State, action: jax.Array) -> jax.Array:
        return self._picked_up_target(state, action)

    def core_step(self, state: State, action: jax.Array):
        """``MiniGridEnv.step`` with boxes that hold objects (``Box.toggle`` puts the contents
        on the box's cell; contents travel with a box that is picked up or dropped)."""
        fwd = front_pos(state)
        cell = get_cell(state.grid, fwd)
        new, reward, terminated, truncated = transition(state, action, self.max_steps)
        task = state.extras
        inside = get_cell(task.contents, fwd)
        empty = jnp.asarray(EMPTY_CELL)
        hands_empty = state.carrying[0] == EMPTY
        opened = (action == TOGGLE) & (cell[0] == BOX)
        picked = (action == PICKUP) & (cell[0] == BOX) & hands_empty
        dropped = (action == DROP) & (state.carrying[0] == BOX) & (cell[0] == EMPTY)
        grid = set_cell(new.grid, fwd, inside, opened)
        contents = set_cell(
            task.contents, fwd, jnp.where(dropped, task.carried, empty), opened | picked | dropped
        )
        carried = jnp.where(picked, inside, jnp.where(dropped, empty, task.carried))
        new = new.replace(grid=grid, extras=task.replace(contents=contents, carried=carried))
        return new, reward, terminated, truncated

    def _hide(self, grid, contents, pos, colour):
        """``add_key``/``add_door``'s key: ``Key(colour)`` at ``pos``, or a grey box holding it."""
        key = G.cell(KEY, colour)
        if not self.key_in_box:
            return G.put(grid, pos, key), contents
        return G.put(grid, pos, G.cell(BOX, BOX_COLOUR)), G.put(contents, pos, key)

    def _finish(self, grid, contents, target, agent, direction, key) -> State:
        # a box a blocking ball covered is gone, and so is what it held
        contents = jnp.where((grid[..., 0] == BOX)[..., None], contents, jnp.asarray(EMPTY_CELL))
        task = HiddenKeys(
            kind=jnp.int32(BALL),
            colour=jnp.int32(TARGET),
            pos=jnp.asarray(target, jnp.int32),
            contents=contents.astype(jnp.uint8),
            carried=jnp.asarray(EMPTY_CELL),
        )
        return self.init_state(grid, agent, direction, key, task)


def _door_cells(rows: int, cols: int):
    """Per room ``(i, j)`` and door index ``d`` (MiniGrid's ``room.door_pos[d]``): the wall
    index into ``keys._walls``'s order (``-1`` where the room has no neighbour)."""
    n_right = rows * (cols - 1)
    index = np.full((cols, rows, 4), -1, np.int32)
    for i in range(cols):
        for j in range(rows):
            if i < cols - 1:
                index[i, j, 0] = index[i + 1, j, 2] = j * (cols - 1) + i
            if j < rows - 1:
                index[i, j, 1] = index[i, j + 1, 3] = n_right + j * cols + i
    return index


class ObstructedMaze1D(_ObstructedMaze):
    """``ObstructedMaze_1Dlhb``: two rooms; the blue ball is in the right one, behind a locked
    door whose key is in the agent's room (in a box if ``key_in_box``; the door blocked by a
    green ball on the agent's side if ``blocked``).

    Ids: ``MiniGrid-ObstructedMaze-1Dl-v0`` (no box, no ball), ``-1Dlh-v0`` (box) and
    ``-1Dlhb-v0`` (both): 11 x 6, ``max_steps`` 288 (``4 * 2 * room_size**2``).
    """

    def generate(self, key: jax.Array) -> State:
        grid, door, u, mid = self._two_rooms(key, 4)
        contents = jnp.broadcast_to(jnp.asarray(EMPTY_CELL), grid.shape)
        # door_colors = _rand_subset(COLOR_NAMES, 6); add_door(0, 0, 0, door_colors[0], locked)
        colour = G.randint(u[0], 0, 6)
        grid = G.put(grid, door, G.cell(DOOR, colour, LOCKED))
        if self.blocked:  # grid.set(door_pos - DIR_TO_VEC[0], Ball(blocking_ball_color))
            grid = G.put(grid, door - jnp.array([1, 0]), G.cell(BALL, BLOCKING))
        s = self.room_size
        grid, contents = self._hide(grid, contents, place_in_room(u[1], grid, s, 0, 0, mid), colour)
        # self.obj, _ = add_object(1, 0, "ball", color=ball_to_find_color)
        target = place_in_room(u[2], grid, s, 1, 0, mid)
        grid = G.put(grid, target, G.cell(BALL, TARGET))
        agent, direction = place_agent(u[3], grid, s, 0, 0)  # place_agent(0, 0)
        return self._finish(grid, contents, target, agent, direction, key)


class ObstructedMazeFull(_ObstructedMaze):
    """``ObstructedMaze_Full`` (and ``_Full_V1`` with ``keys_after_doors``): a 3 x 3 maze. The
    middle room opens (closed doors) onto ``num_quarters`` side rooms; each side room has locked
    doors to its two corner rooms, with their keys inside it; the blue ball is in one of the
    first ``num_quarters`` corners. The agent starts in ``agent_room`` (column, row).

    v0 adds each key right after its door and blocking ball, so the next ball may cover it;
    v1 (``keys_after_doors``) adds a side room's keys after both its doors.
    Ids (16 x 16, ``max_steps = 4 * rooms_visited * 36``): ``2Dl``, ``2Dlh``, ``2Dlhb``
    (agent in (2, 1), one quarter, 576), ``1Q`` (middle, one quarter, 720), ``2Q`` ((2, 1),
    two quarters, 1584), ``Full`` (middle, four, 3600); v1 of ``2Dlhb``, ``1Q``, ``2Q``, ``Full``.
    """

    num_quarters: int = struct.field(pytree_node=False, default=4)
    agent_room: tuple = struct.field(pytree_node=False, default=(1, 1))
    keys_after_doors: bool = struct.field(pytree_node=False, default=False)

    NUM_ROWS = 3
    NUM_COLS = 3

    def _check_rows_cols(self) -> None:
        super()._check_rows_cols()
        name = type(self).__name__
        q = self.num_quarters
        if not isinstance(q, int) or isinstance(q, bool) or not 1 <= q <= 4:
            raise ValueError(f"{name}.num_quarters must be an int in 1..4, got {q!r}")
        room = self.agent_room
        if not (
            isinstance(room, tuple)
            and len(room) == 2
            and all(isinstance(c, int) and 0 <= c < 3 for c in room)
        ):
            raise ValueError(
                f"{name}.agent_room must be a (column, row) tuple of ints in 0..2, got {room!r}"
            )

    def generate(self, key: jax.Array) -> State:
        s, q = self.room_size, self.num_quarters
        base, axis, _ = _walls(s, 3, 3)
        walls = _door_cells(3, 3)
        u = jax.random.uniform(key, (len(base) + 6 + 2 * q + 4,))
        # RoomGrid._gen_grid: room walls, one door cell drawn per wall, the agent in the middle
        grid = jnp.asarray(_rooms(self.width, self.height, s))
        offsets = G.randint(u[: len(base)], 1, s - 1)
        doors = jnp.asarray(base) + offsets[:, None] * jnp.asarray(axis)
        u = u[len(base) :]
        mid = _start_pos(s, 3, 3)
        contents = jnp.broadcast_to(jnp.asarray(EMPTY_CELL), grid.shape)
        colours = jnp.argsort(u[:6])  # door_colors = _rand_subset(COLOR_NAMES, 6)
        u = u[6:]
        # One scan step per quarter (one compiled body, not four): side room i gets the middle
        # room's door i (closed), then its locked doors (i - 1) % 4 and (i + 1) % 4, with
        # colours door_colors[i] and door_colors[(i +- 1) % 6], read from static tables.
        quarters = range(q)
        side = np.array(SIDE_ROOMS[:q], np.int32)
        turn = np.array([[(i + k) % 4 for k in (-1, 1)] for i in quarters], np.int32)
        table = dict(
            middle=walls[1, 1, :q],
            locks=walls[side[:, 0, None], side[:, 1, None], turn],
            ahead=np.asarray(DIR_TO_VEC, np.int32)[turn],
            colour=np.arange(q, dtype=np.int32),
            lock_colour=np.array([[(i + k) % 6 for k in (-1, 1)] for i in quarters], np.int32),
            side=side,
            u=u[: 2 * q].reshape(q, 2),
        )

        def quarter(carry, t):
            grid, contents = carry
            # add_door(*middle_room, door_idx=i, color=door_colors[i], locked=False)
            door = G.select(t["middle"], doors)
            grid = G.put(grid, door, G.cell(DOOR, G.select(t["colour"], colours), CLOSED))

            def hide(grid, contents, k, colour):  # add_key / add_door's key: place_in_room
                pos = place_in_room(t["u"][k], grid, s, t["side"][0], t["side"][1], mid)
                return self._hide(grid, contents, pos, colour)

            for k in range(2):  # k = -1, +1
                colour = G.select(t["lock_colour"][k], colours)
                door = G.select(t["locks"][k], doors)
                grid = G.put(grid, door, G.cell(DOOR, colour, LOCKED))
                if self.blocked:  # grid.set(door_pos - DIR_TO_VEC[door_idx], Ball(...))
                    grid = G.put(grid, door - t["ahead"][k], G.cell(BALL, BLOCKING))
                if not self.keys_after_doors:  # v0: the key right after its door and ball
                    grid, contents = hide(grid, contents, k, colour)
            if self.keys_after_doors:  # v1: add_key for both doors after them
                for k in range(2):
                    colour = G.select(t["lock_colour"][k], colours)
                    grid, contents = hide(grid, contents, k, colour)
            return (grid, contents), None

        (grid, contents), _ = jax.lax.scan(quarter, (grid, contents), table)

        # ball_room = _rand_elem(corners); add_object(*ball_room, "ball", ball_to_find_color)
        corner = G.select(G.randint(u[2 * q], 0, q), jnp.asarray(CORNERS[:q], jnp.int32))
        target = place_in_room(u[2 * q + 1], grid, s, corner[0], corner[1], mid)
        grid = G.put(grid, target, G.cell(BALL, TARGET))
        agent, direction = place_agent(u[2 * q + 2], grid, s, *self.agent_room)
        return self._finish(grid, contents, target, agent, direction, key)


# ----------------------------------------------------------------------------- ids


def _one_door(key_in_box: bool, blocked: bool):
    # ObstructedMaze_1Dlhb: num_rows=1, num_cols=2, num_rooms_visited=2
    width, height = roomgrid_size(ROOM_SIZE, 1, 2)
    return lambda: ObstructedMaze1D(
        width=width,
        height=height,
        max_steps=4 * 2 * ROOM_SIZE**2,
        key_in_box=key_in_box,
        blocked=blocked,
    )


def _full(agent_room, key_in_box, blocked, num_quarters, rooms_visited, v1=False):
    width, height = roomgrid_size(ROOM_SIZE, 3, 3)
    return lambda: ObstructedMazeFull(
        width=width,
        height=height,
        max_steps=4 * rooms_visited * ROOM_SIZE**2,
        key_in_box=key_in_box,
        blocked=blocked,
        num_quarters=num_quarters,
        agent_room=agent_room,
        keys_after_doors=v1,
    )


_FULL = {  # MiniGrid's registrations: agent_room, key_in_box, blocked, quarters, rooms visited
    "2Dl": ((2, 1), False, False, 1, 4),
    "2Dlh": ((2, 1), True, False, 1, 4),
    "2Dlhb": ((2, 1), True, True, 1, 4),
    "1Q": ((1, 1), True, True, 1, 5),
    "2Q": ((2, 1), True, True, 2, 11),
    "Full": ((1, 1), True, True, 4, 25),
}

IDS = {
    "MiniGrid-ObstructedMaze-1Dl-v0": _one_door(False, False),
    "MiniGrid-ObstructedMaze-1Dlh-v0": _one_door(True, False),
    "MiniGrid-ObstructedMaze-1Dlhb-v0": _one_door(True, True),
    **{f"MiniGrid-ObstructedMaze-{name}-v0": _full(*args) for name, args in _FULL.items()},
    **{
        f"MiniGrid-ObstructedMaze-{name}-v1": _full(*_FULL[name], v1=True)
        for name in ("2Dlhb", "1Q", "2Q", "Full")
    },
}
