"""MiniGrid's navigation levels (FourRooms, Crossings, DistShift) with their layout distributions.

Each ``generate`` mirrors the ``_gen_grid`` of the MiniGrid class it names; the comments quote
the MiniGrid call each line reproduces. Every random choice is built constructively with
MiniGrid's distribution (no retry loop under ``jit``): a rejection-sampled ``place_obj`` is the
uniform distribution over the cells it accepts, and a shuffle is a uniform permutation, drawn
here as the ranks of independent random words. These levels step with ``MiniGridEnv.step``'s
rules, so only generation is level-specific. :data:`IDS` maps MiniGrid's ids, with MiniGrid's
per-id defaults, to factories.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import grid as G
from jaxgrid import mission as mission_words
from jaxgrid.constants import EMPTY, EMPTY_CELL, GOAL_CELL, LAVA_CELL, WALL_CELL
from jaxgrid.contents import Contents
from jaxgrid.environment import Environment
from jaxgrid.types import State


def _words_to_uniform(bits: jax.Array) -> jax.Array:
    """float32 in ``[0, 1)`` from uint32 words (their top 24 bits: exact in float32)."""
    return (bits >> 8).astype(jnp.float32) * jnp.float32(2.0**-24)


def _ranks(bits: jax.Array) -> jax.Array:
    """Rank of each word among ``bits``: a uniform permutation of ``0..n-1``.

    Ties (probability below ``n**2 / 2**33``) are broken by position.
    """
    return jnp.argsort(jnp.argsort(bits))


def _pick(values: jax.Array, index: jax.Array) -> jax.Array:
    """``values[index]`` for a 1-D ``values`` and any-shape ``index``, as a select-sum.

    No gather under ``vmap``: these tables have a handful of entries.
    """
    hit = jnp.arange(values.shape[0]) == index[..., None]
    return jnp.sum(jnp.where(hit, values, 0), axis=-1)


def _interior(cell, width: int, height: int) -> bool:
    return (
        isinstance(cell, tuple)
        and len(cell) == 2
        and all(isinstance(c, int) and not isinstance(c, bool) for c in cell)
        and 1 <= cell[0] <= width - 2
        and 1 <= cell[1] <= height - 2
    )


def _require_odd(level, why: str) -> None:
    """``ValueError`` naming the field when the level's width or height is even."""
    for field in ("width", "height"):
        value = getattr(level, field)
        if value % 2 == 0:
            raise ValueError(f"{type(level).__name__}.{field} must be odd ({why}), got {value}")


class FourRooms(Environment):
    """``FourRoomsEnv``: four rooms joined by one gap in each inner wall half; agent and goal
    anywhere.

    The inner walls run along column ``width // 2`` and row ``height // 2``; each of their four
    halves gets one gap drawn uniformly from its interior cells. ``place_agent`` (then the goal's
    ``place_obj``) rejection-samples until it hits an empty cell (not the agent's), which is the
    uniform distribution over those cells: it is drawn directly, so no retry is needed.
    ``agent_start``/``goal_start`` fix the agent's cell (random direction) or the goal's cell,
    as ``FourRoomsEnv(agent_pos=..., goal_pos=...)`` does. MiniGrid only builds 19x19; other odd
    sizes follow the same construction.
    """

    MISSION = "reach the goal"

    agent_start: tuple[int, int] | None = struct.field(pytree_node=False, default=None)
    goal_start: tuple[int, int] | None = struct.field(pytree_node=False, default=None)

    def __post_init__(self):
        super().__post_init__()
        _require_odd(self, "the inner wall sits in the middle, with rooms of equal size on "
                           "both sides inside the outer walls")  # fmt: skip
        for field in ("agent_start", "goal_start"):
            value = getattr(self, field)
            if value is not None and not _interior(value, self.width, self.height):
                raise ValueError(
                    f"FourRooms.{field} must be None or an (x, y) tuple of ints inside the walls "
                    f"(1 .. {self.width - 2}, 1 .. {self.height - 2}), got {value!r}"
                )

    def min_size(self):
        # Each room needs an interior cell for its wall gap: room_w = width // 2 >= 2.
        return 5, 5, "four rooms with at least one interior cell each"

    def generate(self, key: jax.Array) -> State:
        u = jax.random.uniform(key, (7,))
        w, h = self.width, self.height
        xs, ys = G.coords(w, h)
        # horz_wall(0, 0); horz_wall(0, height - 1); vert_wall(0, 0); vert_wall(width - 1, 0)
        grid = jnp.asarray(G.room(w, h))
        room_w, room_h = w // 2, h // 2  # room_w = width // 2; room_h = height // 2
        # vert_wall(xR, yT, room_h) and horz_wall(xL, yB, room_w) for the rooms' rows and
        # columns: together the whole middle column and row.
        inner = (xs == room_w) | (ys == room_h)
        grid = jnp.where(inner[..., None], jnp.asarray(WALL_CELL), grid)
        gaps = (
            (room_w, G.randint(u[0], 1, room_h)),  # i=0, j=0: (xR, _rand_int(yT + 1, yB))
            (G.randint(u[1], 1, room_w), room_h),  # i=0, j=0: (_rand_int(xL + 1, xR), yB)
            (G.randint(u[2], room_w + 1, 2 * room_w), room_h),  # i=1, j=0
            (room_w, G.randint(u[3], room_h + 1, 2 * room_h)),  # i=0, j=1
        )
        for gap in gaps:  # grid.set(*pos, None); four selects
            grid = G.put(grid, gap, EMPTY_CELL)
        direction = G.randint(u[5], 0, 4)  # agent_dir = _rand_int(0, 4)
        if self.agent_start is None:
            agent = G.sample_cell(u[4], G.is_empty(grid))  # place_agent()
        else:
            agent = jnp.asarray(self.agent_start)
            grid = G.put(grid, agent, EMPTY_CELL)  # grid.set(*self._agent_default_pos, None)
        if self.goal_start is None:
            # place_obj(Goal()): an empty cell that is not the agent's
            goal = G.sample_cell(u[6], G.is_empty(grid) & ~G.at((w, h), agent))
        else:
            goal = self.goal_start  # put_obj(goal, *self._goal_default_pos)
        grid = G.put(grid, goal, GOAL_CELL)
        return self.init_state(grid, agent, direction, key)


OBSTACLES = {"lava": LAVA_CELL, "wall": WALL_CELL}


class Crossing(Environment):
    """``CrossingEnv``: rivers of lava or walls, each with one opening, between the agent at
    (1, 1) facing right and the goal in the opposite corner.

    Candidate rivers are the even columns ``2 .. width - 3`` and rows ``2 .. height - 3``;
    ``num_crossings`` of them are chosen uniformly (MiniGrid shuffles the list and keeps a
    prefix), then an order of crossings (a uniform shuffle of one step per river) walks from
    the agent's room to the goal's, opening each river at a uniform cell of the current room's
    span. MiniGrid draws all this without retries, and so does :meth:`generate`: each shuffle is
    the ranks of independent random words, each opening one uniform draw, so every layout has
    a path to the goal. ``obstacle`` is ``"lava"`` (LavaCrossing) or ``"wall"``
    (SimpleCrossing). Sizes must be odd, as MiniGrid asserts, and hold ``num_crossings`` rivers
    (MiniGrid would silently lay fewer). MiniGrid takes one ``size``; a non-square grid here
    puts vertical rivers on its columns and horizontal ones on its rows.
    """

    num_crossings: int = struct.field(pytree_node=False, default=1)
    obstacle: str = struct.field(pytree_node=False, default="lava")

    def __post_init__(self):
        n = self.num_crossings  # min_size depends on it: check it first
        if not isinstance(n, int) or isinstance(n, bool) or n < 0:
            raise ValueError(f"Crossing.num_crossings must be an int >= 0, got {n!r}")
        if self.obstacle not in OBSTACLES:
            raise ValueError(
                f"Crossing.obstacle must be one of {sorted(OBSTACLES)}, got {self.obstacle!r}"
            )
        super().__post_init__()
        _require_odd(self, "rivers lie on the even rows and columns strictly inside the walls")

    def contents(self) -> Contents:
        return Contents(lava=self.obstacle == "lava" and self.num_crossings > 0)

    def mission(self, state: State) -> jax.Array:
        # _gen_mission_lava / _gen_mission_wall
        lead = "avoid the lava" if self.obstacle == "lava" else "find the opening"
        return mission_words.fill(f"{lead} and get to the green goal square")

    def min_size(self):
        # An odd size s has s - 3 candidate rivers (its even rows and columns 2 .. s - 3); 5 is
        # the least that keeps the agent's corner (1, 1) apart from the goal's.
        size = max(5, self.num_crossings + 3)
        size += 1 - size % 2
        why = f"{self.num_crossings} rivers on even rows and columns, agent and goal apart"
        return size, size, why

    def generate(self, key: jax.Array) -> State:
        w, h, n = self.width, self.height, self.num_crossings
        xs, ys = G.coords(w, h)
        cols = np.arange(2, w - 2, 2)  # vertical rivers: range(2, height - 2, 2)
        rows = np.arange(2, h - 2, 2)  # horizontal rivers: range(2, width - 2, 2)
        m = len(cols) + len(rows)
        bits = jax.random.bits(key, (m + 2 * n,), jnp.uint32)
        # wall_rect(0, 0, width, height); put_obj(Goal(), width - 2, height - 2)
        grid = G.put(jnp.asarray(G.room(w, h)), (w - 2, h - 2), GOAL_CELL)
        # rivers = [(v, i) ...] + [(h, j) ...]; np_random.shuffle(rivers);
        # rivers = rivers[: self.num_crossings]
        chosen = _ranks(bits[:m]) < n
        chosen_v, chosen_h = chosen[: len(cols)], chosen[len(cols) :]
        # put_obj(obstacle_type(), i, j) for product(range(1, width - 1), rivers_h) and
        # product(rivers_v, range(1, height - 1))
        river_v = jnp.any(chosen_v[:, None, None] & (xs == cols[:, None, None]), axis=0)
        river_h = jnp.any(chosen_h[:, None, None] & (ys == rows[:, None, None]), axis=0)
        inside = (xs >= 1) & (xs <= w - 2) & (ys >= 1) & (ys <= h - 2)
        obstacle = jnp.asarray(OBSTACLES[self.obstacle])
        grid = jnp.where((inside & (river_v | river_h))[..., None], obstacle, grid)
        # limits_v = [0] + sorted(rivers_v) + [height - 1] (likewise limits_h): unchosen lines
        # sort last as the far wall, so entry k + 1 past the k chosen ones is the far wall.
        limits_v = jnp.concatenate(
            [np.array([0]), jnp.sort(jnp.where(chosen_v, cols, w - 1)), np.array([w - 1])]
        )
        limits_h = jnp.concatenate(
            [np.array([0]), jnp.sort(jnp.where(chosen_h, rows, h - 1)), np.array([h - 1])]
        )
        # path = [h] * len(rivers_v) + [v] * len(rivers_h); np_random.shuffle(path)
        cross_v = _ranks(bits[m : m + n]) < jnp.sum(chosen_v)  # step k is an "h": east
        room_i = jnp.cumsum(cross_v) - cross_v  # vertical rivers crossed before step k
        room_j = jnp.arange(n) - room_i
        u = _words_to_uniform(bits[m + n :])
        # direction h: i = limits_v[room_i + 1];
        #   j = np_random.choice(range(limits_h[room_j] + 1, limits_h[room_j + 1]))
        # direction v: i = np_random.choice(range(limits_v[room_i] + 1, limits_v[room_i + 1]));
        #   j = limits_h[room_j + 1]
        next_v, next_h = _pick(limits_v, room_i + 1), _pick(limits_h, room_j + 1)
        along_v = G.randint(u, _pick(limits_h, room_j) + 1, next_h)  # y of an "h" opening
        along_h = G.randint(u, _pick(limits_v, room_i) + 1, next_v)  # x of a "v" opening
        open_x = jnp.where(cross_v, next_v, along_h)
        open_y = jnp.where(cross_v, along_v, next_h)
        # grid.set(i, j, None) for each step of the path
        opening = jnp.any((xs == open_x[:, None, None]) & (ys == open_y[:, None, None]), axis=0)
        grid = jnp.where(opening[..., None], jnp.asarray(EMPTY_CELL), grid)
        # agent_pos = (1, 1); agent_dir = 0
        return self.init_state(grid, jnp.array([1, 1]), 0, key)


class DistShift(Environment):
    """``DistShiftEnv``: two lava strips between the agent's corner and the goal at the top right.

    Lava lies on row 1 and on row ``strip2_row`` at columns ``3 .. width - 4``; the goal is at
    ``(width - 2, 1)``. The agent starts at ``agent_start`` facing ``agent_start_dir``, or, with
    ``agent_start=None``, at a uniform empty cell with a uniform direction (``place_agent``).
    The height must leave a lava-free row besides rows 1 and ``strip2_row``, so that every
    layout is solvable. MiniGrid builds this level with ``see_through_walls=True``.
    """

    strip2_row: int = struct.field(pytree_node=False, default=2)
    agent_start: tuple[int, int] | None = struct.field(pytree_node=False, default=(1, 1))
    agent_start_dir: int = struct.field(pytree_node=False, default=0)

    def __post_init__(self):
        row = self.strip2_row  # min_size depends on it: check it first
        if not isinstance(row, int) or isinstance(row, bool) or row < 1:
            raise ValueError(f"DistShift.strip2_row must be an int >= 1, got {row!r}")
        if self.agent_start_dir not in (0, 1, 2, 3):
            raise ValueError(
                f"DistShift.agent_start_dir must be 0..3, got {self.agent_start_dir!r}"
            )
        super().__post_init__()
        start = self.agent_start
        if start is not None:
            ok = _interior(start, self.width, self.height)
            if not ok or self.layout()[start[0], start[1], 0] != EMPTY:
                raise ValueError(
                    f"DistShift.agent_start must be None or an (x, y) tuple of ints on an empty "
                    f"cell inside the walls (not the goal or lava), got {start!r}"
                )

    def min_size(self):
        # Rows 1 and strip2_row inside the walls, plus a third interior row to walk around them.
        height = max(self.strip2_row, 3) + 2
        return 4, height, "the goal apart from (1, 1), both lava rows and a lava-free row"

    def contents(self) -> Contents:
        return Contents(lava=self.width > 6)  # the strips span columns 3 .. width - 4

    def layout(self) -> np.ndarray:
        """The fixed grid, uint8 ``(W, H, 3)`` (the agent is not part of it)."""
        w, h = self.width, self.height
        grid = G.room(w, h)  # wall_rect(0, 0, width, height)
        grid[w - 2, 1] = GOAL_CELL  # put_obj(Goal(), *self.goal_pos), goal_pos = (width - 2, 1)
        # for i in range(self.width - 6): grid.set(3 + i, 1, Lava());
        #   grid.set(3 + i, self.strip2_row, Lava())
        grid[3 : w - 3, 1] = LAVA_CELL
        grid[3 : w - 3, self.strip2_row] = LAVA_CELL
        return grid

    def generate(self, key: jax.Array) -> State:
        grid = self.layout()
        if self.agent_start is not None:
            agent, direction = self.agent_start, self.agent_start_dir
        else:  # place_agent(): an empty cell, then _rand_int(0, 4)
            u = jax.random.uniform(key, (2,))
            agent = G.sample_cell(u[0], jnp.asarray(grid[..., 0] == EMPTY))
            direction = G.randint(u[1], 0, 4)
        return self.init_state(grid, agent, direction, key)


def _four_rooms() -> Callable[[], Environment]:
    # FourRoomsEnv: size 19, max_steps 100, see_through_walls=False.
    return lambda: FourRooms(width=19, height=19, max_steps=100)


def _crossing(size: int, n: int, obstacle: str) -> Callable[[], Environment]:
    # CrossingEnv: max_steps 4 * size**2, see_through_walls=False.
    return lambda: Crossing(
        width=size, height=size, max_steps=4 * size**2, num_crossings=n, obstacle=obstacle
    )


def _dist_shift(strip2_row: int) -> Callable[[], Environment]:
    # DistShiftEnv: 9x7, max_steps 4 * width * height, see_through_walls=True.
    return lambda: DistShift(
        width=9, height=7, max_steps=4 * 9 * 7, see_through_walls=True, strip2_row=strip2_row
    )


_CROSSINGS = ((9, 1), (9, 2), (9, 3), (11, 5))

IDS: dict[str, Callable[[], Environment]] = {
    "MiniGrid-FourRooms-v0": _four_rooms(),
    **{f"MiniGrid-LavaCrossingS{s}N{n}-v0": _crossing(s, n, "lava") for s, n in _CROSSINGS},
    **{f"MiniGrid-SimpleCrossingS{s}N{n}-v0": _crossing(s, n, "wall") for s, n in _CROSSINGS},
    "MiniGrid-DistShift1-v0": _dist_shift(2),
    "MiniGrid-DistShift2-v0": _dist_shift(5),
}
