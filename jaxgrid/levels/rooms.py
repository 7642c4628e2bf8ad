"""MiniGrid's MultiRoom, LockedRoom and RedBlueDoors levels, generated natively.

One thing, the room-chain levels of MiniGrid, each a faithful generator, hence its length.

Each ``generate`` mirrors the ``_gen_grid`` of the MiniGrid class it names; the comments quote
the MiniGrid call each line reproduces. A rejection-sampled ``place_obj``/``place_agent`` is the
uniform distribution over the cells it accepts and is drawn directly, a shuffle of colours is
the order of independent uniforms, and a "redraw until it differs" is a uniform choice among
the other values.

MultiRoom's chain of rooms is the one random process that is not redrawn constructively: its
acceptance depends on every room of the chain, so :class:`MultiRoom` runs MiniGrid's own
proposal process (eight tries per room, an attempt given up when a room finds no place) and
keeps the first complete attempt, in a bounded ``lax.while_loop``. Attempts are independent
and the accepted one is the first that completes, so its distribution is the proposal
process's conditioned on completing, which is MiniGrid's, whatever order the random numbers
are drawn in.

MultiRoom and LockedRoom step with ``MiniGridEnv.step``'s rules. RedBlueDoors overrides
``step`` in MiniGrid and here alike: opening the blue door ends the episode, with the success
reward if the red door was open before that step and 0 otherwise (see :class:`RedBlueDoors`).
:data:`IDS` maps MiniGrid's ids, with MiniGrid's per-id defaults, to factories.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import grid as G
from jaxgrid import mission as mission_words
from jaxgrid.constants import (
    BLUE,
    CLOSED,
    DOOR,
    EMPTY_CELL,
    GOAL_CELL,
    KEY,
    LOCKED,
    OPEN,
    RED,
    WALL,
    WALL_CELL,
)
from jaxgrid.contents import ALL_COLOURS, Contents
from jaxgrid.dynamics import get_cell, transition
from jaxgrid.environment import Environment, check_action
from jaxgrid.types import State, TimeStep

NUM_COLOURS = 6  # MiniGrid's COLOR_NAMES


def _check_int(level, field: str, low: int, why: str) -> None:
    value = getattr(level, field)
    if not isinstance(value, int) or isinstance(value, bool) or value < low:
        raise ValueError(
            f"{type(level).__name__}.{field} must be an int >= {low} ({why}), got {value!r}"
        )


# ---------------------------------------------------------------------------- MultiRoom

MIN_ROOM_SIZE = 4  # _placeRoom(..., minSz=4, ...)
TRIES = 8  # _placeRoom: for i in range(0, 8): ... one proposal for the next room per try
ATTEMPTS_PER_ROUND = 4  # chain attempts drawn side by side in one loop iteration
MAX_ROUNDS = 256  # at most 1024 attempts per reset
EXTRA_UNIFORMS = 3  # beside each attempt: the agent's cell and direction, the goal's cell


def _first_room_pairs(tops: int, sizes: range, limit: int) -> np.ndarray:
    """``(top, size)`` pairs of the first room along one axis that ``_placeRoom`` keeps.

    ``top`` is ``_rand_int(0, tops)``, ``size`` is ``_rand_int(minSz, maxSz + 1)``; the room is
    kept when ``top + size <= limit``. Returns int32 ``(K, 2)``.
    """
    pairs = [(t, s) for t in range(tops) for s in sizes if t + s <= limit]
    return np.array(pairs, np.int32).reshape(-1, 2)


class MultiRoom(Environment):
    """``MultiRoomEnv``: a chain of rooms joined by closed doors; the goal is in the last room.

    ``_gen_grid`` draws the number of rooms in ``min_num_rooms .. max_num_rooms``, then builds
    chains of rooms (sides ``4 .. max_room_size``, walls included) until one has that many:
    the first room's top-left corner is uniform in ``[0, width - 2)`` along both axes (MiniGrid
    draws its ``y`` from the width too), each next room leaves its predecessor through a door on
    one of the three walls other than the one it was entered by, and is kept if it lies inside
    the grid (its bottom wall above the last row) and apart from every earlier room but its
    predecessor; eight proposals are tried per room and a chain ends at the first room with
    none kept. The doors are closed, each of a uniform colour other than the previous door's;
    the agent is placed uniformly in the first room with a uniform direction, the goal
    uniformly in the last room. There are no outer walls.

    The first room is drawn uniformly among the corners and sizes that fit, which conditions
    the attempt on what ``_placeRoom`` checks first and leaves the accepted distribution
    unchanged. Attempts run :data:`ATTEMPTS_PER_ROUND` at a time, at most :data:`MAX_ROUNDS`
    rounds (1024 attempts). An attempt completes with probability 0.34 at
    ``MiniGrid-MultiRoom-N6-v0`` (0.61 at ``N4-S5-v0``, 0.81 at ``N4-S5-v1``, 0.998 at
    ``N2-S4-v0``; measured over 200000 attempts), so a reset reaches the cap with probability
    ``0.66**1024 < 1e-180``. A grid too small for the rooms asked, where MiniGrid would retry
    forever, gets the longest chain found in the 1024 attempts (the first of that length, as
    MiniGrid's ``roomList``) and fewer rooms than asked.

    Random numbers come from one counter block of the layout key per round
    (:func:`jaxgrid.grid.counter_uniforms`), the agent's, goal's and doors' ones drawn beside
    each attempt: every hash of a key is a large kernel that XLA compiles separately, and
    this keeps the reset and the auto-resetting step within a few seconds of compile.
    """

    MISSION = "traverse the rooms to get to the goal"

    min_num_rooms: int = struct.field(pytree_node=False, default=6)
    max_num_rooms: int = struct.field(pytree_node=False, default=6)
    max_room_size: int = struct.field(pytree_node=False, default=10)

    def __post_init__(self):
        _check_int(self, "min_num_rooms", 1, "a chain has a first room")
        _check_int(self, "max_num_rooms", self.min_num_rooms, "at least min_num_rooms")
        _check_int(self, "max_room_size", MIN_ROOM_SIZE, "rooms are 4 cells wide at least")
        super().__post_init__()

    def min_size(self):
        # The first room's corner (0, 0) with sides 4: its right wall in the last column, its
        # bottom wall above the last row (topY + sizeY < height).
        return MIN_ROOM_SIZE, MIN_ROOM_SIZE + 1, "a first room of 4 x 4 cells above the last row"

    def contents(self) -> Contents:
        return Contents(door=ALL_COLOURS if self.max_num_rooms > 1 else ())

    def _propose(self, u, parent, older, rooms):
        """One room's :data:`TRIES` proposals; returns ``(kept, room, entry wall)``.

        ``u`` is ``(TRIES, 5)`` uniforms; ``parent`` is the row ``(top x, top y, size x,
        size y, entry wall)`` of the room the door leaves; ``older`` (bool ``(M,)``) marks the
        rooms the new one must lie apart from (``roomList[:-1]``) among the first ``M`` rows of
        ``rooms`` (int32 ``(M, 6)``, see :meth:`_attempt`). ``room`` is the new room's row.
        """
        px, py, psx, psy, parent_entry = (parent[i] for i in range(5))
        # wallSet = {0, 1, 2, 3} - {entryDoorWall}; exitDoorWall = _rand_elem(sorted(wallSet))
        index = G.randint(u[:, 0], 0, 3)
        exit_wall = index + (index >= parent_entry)
        # exit on the right/left wall: topY + _rand_int(1, sizeY - 1); south/north: topX + ...
        door_x = jnp.where(
            exit_wall == 0,
            px + psx - 1,
            jnp.where(exit_wall == 2, px, px + G.randint(u[:, 1], 1, psx - 1)),
        )
        door_y = jnp.where(
            exit_wall == 1,
            py + psy - 1,
            jnp.where(exit_wall == 3, py, py + G.randint(u[:, 1], 1, psy - 1)),
        )
        entry = (exit_wall + 2) % 4  # nextEntryWall = (exitDoorWall + 2) % 4
        # sizeX = _rand_int(minSz, maxSz + 1); sizeY = _rand_int(minSz, maxSz + 1)
        sx = G.randint(u[:, 2], MIN_ROOM_SIZE, self.max_room_size + 1)
        sy = G.randint(u[:, 3], MIN_ROOM_SIZE, self.max_room_size + 1)
        # entry on the right: topX = x - sizeX + 1; on the left: topX = x; south or top:
        # topX = _rand_int(x - sizeX + 2, x); likewise topY
        tx = jnp.where(
            entry == 0,
            door_x - sx + 1,
            jnp.where(entry == 2, door_x, G.randint(u[:, 4], door_x - sx + 2, door_x)),
        )
        ty = jnp.where(
            entry == 1,
            door_y - sy + 1,
            jnp.where(entry == 3, door_y, G.randint(u[:, 4], door_y - sy + 2, door_y)),
        )
        # if topX < 0 or topY < 0: return False
        # if topX + sizeX > self.width or topY + sizeY >= self.height: return False
        inside = (tx >= 0) & (ty >= 0) & (tx + sx <= self.width) & (ty + sy < self.height)
        # for room in roomList[:-1]: nonOverlap = (topX + sizeX < room.top[0] or ...)
        rx, ry, rsx, rsy = (rooms[None, :, i] for i in range(4))
        apart = (
            (tx[:, None] + sx[:, None] < rx)
            | (rx + rsx <= tx[:, None])
            | (ty[:, None] + sy[:, None] < ry)
            | (ry + rsy <= ty[:, None])
        )
        kept = inside & jnp.all(apart | ~older[None, :], axis=1)
        # the first try kept wins: "if success: break" (one select for the whole row)
        row = G.select(jnp.argmax(kept), jnp.stack([tx, ty, sx, sy, door_x, door_y, entry], axis=1))
        return jnp.any(kept), row[:6], row[6]

    def _attempt(self, u, num_rooms):
        """One chain attempt (a call of ``_placeRoom`` from ``_gen_grid``) from uniforms ``u``.

        Returns ``(rooms, count)``: int32 ``(N, 6)`` rows ``(top x, top y, size x, size y,
        entry door x, entry door y)`` (the door unused for the first room; rows past ``count``
        zero) and the number of rooms placed. One packed array keeps the per-room updates of
        the scan to one select.
        """
        n = self.max_num_rooms
        # entryDoorPos = (_rand_int(0, width - 2), _rand_int(0, width - 2)), then the sizes;
        # kept if topX + sizeX <= width and topY + sizeY < height: drawn among those kept.
        sizes = range(MIN_ROOM_SIZE, self.max_room_size + 1)
        first = []
        for axis, limit in ((0, self.width), (1, self.height - 1)):
            pairs = _first_room_pairs(self.width - 2, sizes, limit)
            first.append(jnp.asarray(pairs)[G.randint(u[axis], 0, len(pairs))])
        (tx, sx), (ty, sy) = first
        room0 = jnp.stack([tx, ty, sx, sy, jnp.int32(0), jnp.int32(0)])
        rooms = jnp.where((jnp.arange(n) == 0)[:, None], room0, 0)
        older_rows = max(n - 2, 0)  # roomList[:-1] is never one of the last two of N rows

        def next_room(carry, xs):
            rooms, parent, count, alive = carry
            k, u_k = xs
            # roomList[:-1]: rooms 0 .. k - 2, every room placed but the parent
            older = jnp.arange(older_rows) < k - 1
            kept, room, entry = self._propose(u_k, parent, older, rooms[:older_rows])
            # "if numLeft == 1: return True"; a room with no proposal kept ends the chain
            placed = alive & kept & (k < num_rooms)
            rooms = jnp.where(((jnp.arange(n) == k) & placed)[:, None], room, rooms)
            parent = jnp.where(placed, jnp.concatenate([room[:4], entry[None]]), parent)
            return (rooms, parent, count + placed, placed), None

        chain_u = u[2:].reshape(n - 1, TRIES, 5)
        parent = jnp.stack([tx, ty, sx, sy, jnp.int32(2)])  # the first room's entryDoorWall=2
        carry = (rooms, parent, jnp.int32(1), jnp.bool_(True))
        (rooms, _, count, _), _ = jax.lax.scan(next_room, carry, (jnp.arange(1, n), chain_u))
        return rooms, count

    def _rooms(self, key, num_rooms):
        """MiniGrid's ``roomList``: ``while len(roomList) < numRooms``, attempts in rounds of
        :data:`ATTEMPTS_PER_ROUND`; the first complete attempt, or after :data:`MAX_ROUNDS`
        the first of the most rooms.

        Returns ``(rooms, count, extra)`` (``rooms`` and ``count`` as :meth:`_attempt`'s);
        ``extra`` is :data:`EXTRA_UNIFORMS` plus ``N`` uniforms drawn beside the kept attempt
        and independent of it, for the rest of the layout, so that a reset hashes its key in
        one place.
        """
        n = self.max_num_rooms
        chain = 2 + (n - 1) * TRIES * 5

        def round_(carry):
            i, best = carry
            u = G.counter_uniforms(key, 1 + i, (ATTEMPTS_PER_ROUND, chain + EXTRA_UNIFORMS + n))
            rooms, count = jax.vmap(self._attempt, in_axes=(0, None))(u[:, :chain], num_rooms)
            j = jnp.argmax(count)  # the first attempt with the most rooms
            found = (G.select(j, rooms), jnp.max(count), G.select(j, u[:, chain:]))
            longer = found[1] > best[1]  # if len(curRoomList) > len(roomList): replace it
            best = jax.tree.map(lambda new, old: jnp.where(longer, new, old), found, best)
            return i + 1, best

        def more(carry):
            i, best = carry
            return (i < MAX_ROUNDS) & (best[1] < num_rooms)

        first = (jnp.zeros((n, 6), jnp.int32), jnp.int32(0), jnp.zeros(EXTRA_UNIFORMS + n))
        _, best = jax.lax.while_loop(more, round_, (jnp.int32(0), first))
        return best

    def generate(self, key: jax.Array) -> State:
        n, w, h = self.max_num_rooms, self.width, self.height
        # numRooms = _rand_int(minNumRooms, maxNumRooms + 1); no draw for MiniGrid's ids
        num_rooms = jnp.int32(self.min_num_rooms)
        if self.max_num_rooms > self.min_num_rooms:
            u0 = G.counter_uniforms(key, 0, (1,))[0]
            num_rooms = G.randint(u0, self.min_num_rooms, self.max_num_rooms + 1)
        rooms, count, u = self._rooms(key, num_rooms)
        tops, sizes, doors = rooms[:, 0:2], rooms[:, 2:4], rooms[:, 4:6]
        placed = jnp.arange(n) < count
        # for each room: the top, bottom, left and right walls of its rectangle
        xs, ys = G.coords(w, h)
        x0, y0 = tops[:, 0, None, None], tops[:, 1, None, None]
        x1 = x0 + sizes[:, 0, None, None] - 1
        y1 = y0 + sizes[:, 1, None, None] - 1
        in_rect = (xs >= x0) & (xs <= x1) & (ys >= y0) & (ys <= y1)
        border = in_rect & ((xs == x0) | (xs == x1) | (ys == y0) | (ys == y1))
        walls = jnp.any(border & placed[:, None, None], axis=0)
        grid = jnp.where(walls[..., None], jnp.asarray(WALL_CELL), jnp.asarray(EMPTY_CELL))
        # doorColor = _rand_elem(sorted(set(COLOR_NAMES) - {prevDoorColor})): the previous
        # colour plus 1 .. 5 (mod 6) is uniform among the other five
        steps = jnp.concatenate(
            [G.randint(u[3:4], 0, NUM_COLOURS), 1 + G.randint(u[4:], 0, NUM_COLOURS - 1)]
        )
        colours = G.prefix_sum(steps[: n - 1]) % NUM_COLOURS  # colours[k - 1]: room k's door
        # grid.set(*room.entryDoorPos, Door(doorColor)) for rooms 1 .. count - 1
        here = (xs == doors[1:, 0, None, None]) & (ys == doors[1:, 1, None, None])
        here = here & placed[1:, None, None]
        colour = jnp.sum(jnp.where(here, colours[:, None, None], 0), axis=0)
        door = jnp.stack([jnp.full_like(colour, DOOR), colour, jnp.full_like(colour, CLOSED)], -1)
        grid = jnp.where(jnp.any(here, axis=0)[..., None], door.astype(jnp.uint8), grid)
        # place_agent(roomList[0].top, roomList[0].size): an empty cell of the first room
        agent = G.sample_cell(u[0], G.is_empty(grid) & in_rect[0])
        direction = G.randint(u[1], 0, 4)
        # place_obj(Goal(), roomList[-1].top, roomList[-1].size): not the agent's cell either
        last = jnp.any(in_rect & (jnp.arange(n) == count - 1)[:, None, None], axis=0)
        goal = G.sample_cell(u[2], G.is_empty(grid) & last & ~G.at((w, h), agent))
        grid = G.put(grid, goal, GOAL_CELL)
        return self.init_state(grid, agent, direction, key)


# --------------------------------------------------------------------------- LockedRoom


@struct.dataclass
class KeyRoom:
    """LockedRoom's mission: the locked door's colour (its key's) and the colour of the door
    of the room holding the key, int32 scalars. The key can move, so both are kept."""

    locked_colour: jax.Array
    key_room_colour: jax.Array


class LockedRoom(Environment):
    """``LockedRoomEnv``: six rooms off a central hallway, one locked with the goal inside;
    the key is in another room.

    The hallway lies between the walls at columns ``width // 2 - 2`` and ``width // 2 + 2``;
    rows ``0``, ``height // 3`` and ``2 * (height // 3)`` split each side into three rooms,
    entered by a door three cells below the room's top wall. The locked room is uniform among
    the six, the goal uniform in it; the six doors take a uniform permutation of the six
    colours; the key (of the locked door's colour) lies uniformly in a uniform other room; the
    agent stands uniformly in the hallway with a uniform direction; ``state.extras`` is a
    :class:`KeyRoom`, the colours the mission names. Goal and key are drawn from
    ``LockedRoom.rand_pos``'s rectangle (rooms of ``height // 3 + 1`` rows). MiniGrid builds
    only square sizes; here the width must be odd and the height not a multiple of 3 (other
    sizes put MiniGrid's goal or key on a wall), at least 9 x 13 (a door below a room's top
    wall, interior cells on both sides).
    """

    def __post_init__(self):
        super().__post_init__()
        if self.width % 2 == 0:
            raise ValueError(
                f"LockedRoom.width must be odd (the right rooms are as wide as the left ones), "
                f"got {self.width}"
            )
        if self.height % 3 == 0:
            raise ValueError(
                f"LockedRoom.height must not be a multiple of 3 (the bottom rooms' "
                f"rand_pos rectangle would reach the outer wall), got {self.height}"
            )

    def min_size(self):
        return 9, 13, "three rooms of one interior column on each side, doors 3 below the top"

    CONTENTS = Contents(door=ALL_COLOURS, key=ALL_COLOURS)

    def rooms(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(tops, sizes, doors)``, int32 ``(6, 2)`` each, in MiniGrid's ``self.rooms`` order
        (left then right, top to bottom)."""
        left, right = self.width // 2 - 2, self.width // 2 + 2  # lWallIdx, rWallIdx
        tops, doors = [], []
        for n in range(3):  # j = n * (height // 3)
            j = n * (self.height // 3)
            tops += [(0, j), (right, j)]
            doors += [(left, j + 3), (right, j + 3)]
        sizes = [(left + 1, self.height // 3 + 1)] * 6  # roomW, roomH
        return tuple(np.array(a, np.int32) for a in (tops, sizes, doors))

    def layout(self) -> np.ndarray:
        """The walls, uint8 ``(W, H, 3)``: outer, hallway and room-splitting walls."""
        w, h = self.width, self.height
        grid = G.room(w, h)
        left, right = w // 2 - 2, w // 2 + 2
        grid[left, :] = grid[right, :] = WALL_CELL  # hallway walls
        for n in range(3):  # room splitting walls
            grid[:left, n * (h // 3)] = WALL_CELL
            grid[right:, n * (h // 3)] = WALL_CELL
        return grid

    def mission(self, state: State) -> jax.Array:
        task = state.extras
        return mission_words.fill(
            "get the {key_colour} key from the {room_colour} room, unlock the {door_colour} "
            "door and go to the goal",
            key_colour=task.locked_colour,
            room_colour=task.key_room_colour,
            door_colour=task.locked_colour,
        )

    def generate(self, key: jax.Array) -> State:
        w, h = self.width, self.height
        tops, sizes, doors = (jnp.asarray(a) for a in self.rooms())
        u = jax.random.uniform(key, (14,))
        grid = jnp.asarray(self.layout())

        # LockedRoom.rand_pos: _rand_pos(topX + 1, topX + sizeX - 1, topY + 1, topY + sizeY - 1)
        def rand_pos(room, ux, uy):
            (x, y), (sx, sy) = G.select(room, tops), G.select(room, sizes)
            return jnp.stack([G.randint(ux, x + 1, x + sx - 1), G.randint(uy, y + 1, y + sy - 1)])

        locked = G.randint(u[0], 0, 6)  # lockedRoom = _rand_elem(self.rooms)
        grid = G.put(grid, rand_pos(locked, u[1], u[2]), GOAL_CELL)
        # colors = set(COLOR_NAMES); for room in self.rooms: color = _rand_elem(sorted(colors));
        # colors.remove(color): a uniform permutation, the order of six uniforms
        colours = jnp.argsort(u[3:9]).astype(jnp.int32)
        xs, ys = G.coords(w, h)
        here = (xs == doors[:, 0, None, None]) & (ys == doors[:, 1, None, None])
        state = jnp.where(jnp.arange(6) == locked, LOCKED, CLOSED)
        per_door = jnp.stack([jnp.full(6, DOOR), colours, state], -1)  # Door(color, is_locked=..)
        door_cells = jnp.sum(jnp.where(here[..., None], per_door[:, None, None], 0), axis=0)
        grid = jnp.where(jnp.any(here, axis=0)[..., None], door_cells.astype(jnp.uint8), grid)
        # while True: keyRoom = _rand_elem(self.rooms); if keyRoom != lockedRoom: break
        other = G.randint(u[9], 0, 5)
        key_room = other + (other >= locked)
        key_colour = G.select(locked, colours)  # Key(lockedRoom.color)
        grid = G.put(grid, rand_pos(key_room, u[10], u[11]), G.cell(KEY, key_colour))
        # place_agent(top=(lWallIdx, 0), size=(rWallIdx - lWallIdx, height))
        left, right = w // 2 - 2, w // 2 + 2
        hallway = (xs >= left) & (xs < right)
        agent = G.sample_cell(u[12], G.is_empty(grid) & hallway)
        task = KeyRoom(key_colour, G.select(key_room, colours))
        return self.init_state(grid, agent, G.randint(u[13], 0, 4), key, task)


# ------------------------------------------------------------------------- RedBlueDoors


@struct.dataclass
class DoorPair:
    """The cells of RedBlueDoors' two doors (MiniGrid's ``self.red_door``/``self.blue_door``),
    int32 ``(2,)`` each. Doors never move, so a door's state is read from its cell."""

    red: jax.Array
    blue: jax.Array


def _is_open(grid, pos) -> jax.Array:
    cell = get_cell(grid, pos)
    return (cell[0] == DOOR) & (cell[2] == OPEN)


class RedBlueDoors(Environment):
    """``RedBlueDoorEnv``: a square room with a red door in its left wall and a blue door in
    its right wall; open the red one, then the blue one.

    The room is ``height x height`` cells (walls included) at column ``(width - height) // 2``
    (MiniGrid's ``size // 2`` at its only width, ``2 * size``), inside the outer walls. The
    agent is uniform in the room with a uniform direction; each door's row is uniform among
    the wall's inner cells. The width must leave a free column outside each door (at least
    ``height + 4``; MiniGrid's size 3 puts the red door against the outer wall).

    ``step`` is ``MiniGridEnv.step``, then MiniGrid's rule: if the blue door is open after the
    step, the episode terminates, with ``reward = 1 - 0.9 * step_count / max_steps`` if the red
    door was open before the step and 0 otherwise; else, if the red door is open after the step
    and the blue one was open before it (it was just closed), the episode terminates with 0.
    As in MiniGrid, stepping on after termination applies the rule again. The doors' cells are
    in ``state.extras`` (:class:`DoorPair`). Defaults (``MiniGrid-RedBlueDoors-8x8-v0``):
    16 x 8, ``max_steps`` 1280.
    """

    MISSION = "open the red door then the blue door"

    def min_size(self):
        # A room of one interior cell, and a free column between each door and the outer wall:
        # (width - height) // 2 >= 2 on the left, as many or one more on the right.
        return self.height + 4, 3, "the square room of side height and a free column each side"

    CONTENTS = Contents(door={"red", "blue"})

    def generate(self, key: jax.Array) -> State:
        w, size = self.width, self.height
        left = (w - size) // 2  # self.size // 2
        u = jax.random.uniform(key, (4,))
        # wall_rect(0, 0, 2 * size, size); wall_rect(size // 2, 0, size, size)
        grid = G.room(w, size)
        grid[left, :] = grid[left + size - 1, :] = WALL_CELL
        xs, ys = G.coords(w, size)
        # place_agent(top=(size // 2, 0), size=(size, size))
        room = (xs >= left) & (xs < left + size)
        agent = G.sample_cell(u[0], jnp.asarray((grid[..., 0] != WALL) & room))
        direction = G.randint(u[1], 0, 4)
        # grid.set(size // 2, _rand_int(1, size - 1), Door("red"))
        red = jnp.stack([jnp.int32(left), G.randint(u[2], 1, size - 1)])
        # grid.set(size // 2 + size - 1, _rand_int(1, size - 1), Door("blue"))
        blue = jnp.stack([jnp.int32(left + size - 1), G.randint(u[3], 1, size - 1)])
        grid = G.put(grid, red, G.cell(DOOR, RED, CLOSED))
        grid = G.put(grid, blue, G.cell(DOOR, BLUE, CLOSED))
        return self.init_state(grid, agent, direction, key, DoorPair(red=red, blue=blue))

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """``MiniGridEnv.step``, then the red-then-blue rule (see the class docstring)."""
        check_action(action)
        doors = state.extras
        red_before = _is_open(state.grid, doors.red)  # self.red_door.is_open
        blue_before = _is_open(state.grid, doors.blue)
        state, reward, terminated, truncated = transition(state, action, self.max_steps)
        red_after = _is_open(state.grid, doors.red)
        blue_after = _is_open(state.grid, doors.blue)
        success = 1.0 - 0.9 * (state.step_count.astype(jnp.float32) / self.max_steps)
        # if blue_door_opened_after: reward = self._reward() if red_door_opened_before else 0
        # elif red_door_opened_after and blue_door_opened_before: reward = 0
        reward = jnp.where(
            blue_after,
            jnp.where(red_before, success, 0.0),
            jnp.where(red_after & blue_before, 0.0, reward),
        ).astype(jnp.float32)
        terminated = terminated | blue_after | (red_after & blue_before)
        return state, self.make_timestep(state, reward, terminated, truncated)


# ----------------------------------------------------------------------------------- ids


def _multi_room(num_rooms: int, max_room_size: int = 10) -> Callable[[], Environment]:
    # MultiRoomEnv(minNumRooms=n, maxNumRooms=n, maxRoomSize): 25 x 25, max_steps 20 * n.
    return lambda: MultiRoom(
        width=25,
        height=25,
        max_steps=20 * num_rooms,
        min_num_rooms=num_rooms,
        max_num_rooms=num_rooms,
        max_room_size=max_room_size,
    )


def _red_blue_doors(size: int) -> Callable[[], Environment]:
    # RedBlueDoorEnv(size): 2 * size x size, max_steps 20 * size**2.
    return lambda: RedBlueDoors(width=2 * size, height=size, max_steps=20 * size**2)


IDS: dict[str, Callable[[], Environment]] = {
    "MiniGrid-MultiRoom-N2-S4-v0": _multi_room(2, 4),
    "MiniGrid-MultiRoom-N4-S5-v0": _multi_room(6, 5),  # MiniGrid's legacy id: six rooms
    "MiniGrid-MultiRoom-N4-S5-v1": _multi_room(4, 5),
    "MiniGrid-MultiRoom-N6-v0": _multi_room(6),
    # LockedRoomEnv(size=19): max_steps 10 * size.
    "MiniGrid-LockedRoom-v0": lambda: LockedRoom(width=19, height=19, max_steps=190),
    "MiniGrid-RedBlueDoors-6x6-v0": _red_blue_doors(6),
    "MiniGrid-RedBlueDoors-8x8-v0": _red_blue_doors(8),
}
