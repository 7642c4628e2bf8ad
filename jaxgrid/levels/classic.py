"""MiniGrid's classic levels with the same layout distributions and defaults.

Each ``generate`` mirrors the ``_gen_grid`` of the MiniGrid class it names; the comments
quote the MiniGrid call each line reproduces. Layout-distribution tests compare many resets
against MiniGrid's own generator.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from jaxgrid import grid as G
from jaxgrid.constants import DOOR, GOAL_CELL, KEY, LAVA_CELL, LOCKED, WALL_CELL, YELLOW
from jaxgrid.contents import Contents
from jaxgrid.environment import Environment
from jaxgrid.types import State


class Empty(Environment):
    """``EmptyEnv``: a walled room with the goal in the bottom-right corner.

    ``random_start=False`` puts the agent at (1, 1) facing right (``MiniGrid-Empty-NxN``);
    ``True`` places it uniformly with a random direction (``MiniGrid-Empty-Random-NxN``).
    MiniGrid builds this level with ``see_through_walls=True``.
    """

    random_start: bool = struct.field(pytree_node=False, default=False)

    def __post_init__(self):
        super().__post_init__()
        if self.width == 3 and self.height == 3:
            raise ValueError(
                "Empty.width and Empty.height cannot both be 3: the one interior cell cannot "
                "hold both the agent and the goal (one of them must be at least 4)"
            )

    def min_size(self):
        return 3, 3, "walls around an interior that holds the agent and the goal"

    def generate(self, key: jax.Array) -> State:
        u = jax.random.uniform(key, (2,))
        grid = jnp.asarray(G.room(self.width, self.height))
        grid = G.put(grid, (self.width - 2, self.height - 2), GOAL_CELL)
        if self.random_start:  # place_agent(): any empty cell, random direction
            pos = G.sample_cell(u[0], G.is_empty(grid))
            direction = G.randint(u[1], 0, 4)
        else:
            pos, direction = jnp.array([1, 1]), 0
        return self.init_state(grid, pos, direction, key)


class DoorKey(Environment):
    """``DoorKeyEnv``: a locked yellow door in a random wall, its key on the agent's side."""

    MISSION = "use the key to open the door and then get to the goal"

    CONTENTS = Contents(door={"yellow"}, key={"yellow"})

    def min_size(self):
        # Wall, the agent's column, the door's wall, the goal's column, wall; the agent's
        # column holds agent and key, and the door's row is drawn from 1 .. height - 3.
        return 5, 4, "room for the agent and key, the door wall and the goal"

    def generate(self, key: jax.Array) -> State:
        u = jax.random.uniform(key, (5,))  # one draw for all: random bits dominate reset cost
        w, h = self.width, self.height
        xs, _ = G.coords(w, h)
        grid = jnp.asarray(G.room(w, h))
        grid = G.put(grid, (w - 2, h - 2), GOAL_CELL)  # put_obj(Goal(), w - 2, h - 2)
        split = G.randint(u[0], 2, w - 2)  # _rand_int(2, width - 2)
        grid = jnp.where((xs == split)[..., None], jnp.asarray(WALL_CELL), grid)  # vert_wall
        left = jnp.asarray(xs) < split
        agent = G.sample_cell(u[1], left & G.is_empty(grid))  # place_agent(size=(split, h))
        direction = G.randint(u[2], 0, 4)
        door_y = G.randint(u[3], 1, h - 2)  # _rand_int(1, height - 2)
        grid = G.put(grid, (split, door_y), G.cell(DOOR, YELLOW, LOCKED))
        free = left & G.is_empty(grid)
        free = free & ~G.at((w, h), agent)  # place_obj never lands on the agent
        key_pos = G.sample_cell(u[4], free)
        grid = G.put(grid, key_pos, G.cell(KEY, YELLOW, 0))
        return self.init_state(grid, agent, direction, key)


class LavaGap(Environment):
    """``LavaGapEnv``: a vertical lava strip with a one-cell gap; agent at (1, 1) facing right."""

    MISSION = "avoid the lava and get to the green goal square"

    CONTENTS = Contents(lava=True)

    def min_size(self):
        # The strip's column is drawn from 2 .. width - 3: between the agent and the goal.
        return 5, 3, "the agent's column, the lava strip and the goal's column inside the walls"

    def generate(self, key: jax.Array) -> State:
        u = jax.random.uniform(key, (2,))
        w, h = self.width, self.height
        xs, ys = G.coords(w, h)
        grid = jnp.asarray(G.room(w, h))
        grid = G.put(grid, (w - 2, h - 2), GOAL_CELL)
        gap_x = G.randint(u[0], 2, w - 2)  # _rand_int(2, width - 2)
        gap_y = G.randint(u[1], 1, h - 1)  # _rand_int(1, height - 1)
        strip = (xs == gap_x) & (ys >= 1) & (ys < h - 1) & (ys != gap_y)
        grid = jnp.where(strip[..., None], jnp.asarray(LAVA_CELL), grid)
        return self.init_state(grid, jnp.array([1, 1]), 0, key)
