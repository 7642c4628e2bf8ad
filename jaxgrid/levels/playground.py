"""MiniGrid's Playground level, generated natively.

``generate`` mirrors ``PlaygroundEnv._gen_grid``; the comments quote the MiniGrid call each
line reproduces. Door rows/columns and colours are plain uniform draws; ``place_agent`` and
``place_obj`` rejection-sample the whole grid for an empty cell (not the agent's), and are
drawn here directly from the uniform distribution over the cells they accept. The level
steps with ``MiniGridEnv.step``'s rules and has no mission (MiniGrid's is ``""``).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp

from jaxgrid import grid as G
from jaxgrid.constants import BALL, BOX, CLOSED, DOOR, EMPTY_CELL, KEY, WALL_CELL
from jaxgrid.contents import ALL_COLOURS, Contents
from jaxgrid.environment import Environment
from jaxgrid.types import State

NUM_COLOURS = 6  # MiniGrid's COLOR_NAMES
NUM_OBJECTS = 12  # for i in range(0, 12): ... self.place_obj(obj)
TYPES = (KEY, BALL, BOX)  # types = ["key", "ball", "box"]


class Playground(Environment):
    """``PlaygroundEnv``: a 3 x 3 lattice of rooms joined by closed doors, with twelve keys,
    balls and boxes lying about.

    Rooms are ``width // 3`` by ``height // 3`` cells, walls included. Each wall between two
    neighbouring rooms has one closed door of a uniform colour, at a uniform cell of the wall
    that is not a corner's neighbour's neighbour (MiniGrid's ``_rand_int(yT + 1, yB - 1)``).
    The agent stands on a uniform empty cell with a uniform direction; then each object is a
    uniform (type, colour) pair on a uniform empty cell that is not the agent's. MiniGrid
    builds 19 x 19 only; here each side must be at least 10 (rooms of at least 3 cells along
    it, walls included, so each wall has a cell for its door).
    """

    MISSION = ""  # "No explicit mission in this environment"

    def min_size(self):
        return 10, 10, "three rooms of at least three cells along each side"

    def contents(self) -> Contents:
        every = ALL_COLOURS
        return Contents(door=every, key=every, ball=every, box=every)

    def doors(self) -> list[tuple[bool, int, int, int]]:
        """Per wall with a door, in MiniGrid's order: ``(vertical, fixed, low, high)``, the
        door at ``(fixed, y)`` (vertical wall) or ``(x, fixed)``, ``y`` or ``x`` uniform in
        ``low .. high - 1``."""
        rw, rh = self.width // 3, self.height // 3  # roomW, roomH
        walls = []
        for j in range(3):
            for i in range(3):
                xl, yt = i * rw, j * rh
                xr, yb = xl + rw, yt + rh
                if i + 1 < 3:  # pos = (xR, self._rand_int(yT + 1, yB - 1))
                    walls.append((True, xr, yt + 1, yb - 1))
                if j + 1 < 3:  # pos = (self._rand_int(xL + 1, xR - 1), yB)
                    walls.append((False, yb, xl + 1, xr - 1))
        return walls

    def layout(self) -> jax.Array:
        """The walls, uint8 ``(W, H, 3)``, before any door."""
        w, h = self.width, self.height
        rw, rh = w // 3, h // 3
        xs, ys = G.coords(w, h)
        wall = (xs == 0) | (xs == w - 1) | (ys == 0) | (ys == h - 1)
        for k in (1, 2):
            wall |= (xs == k * rw) & (ys < 3 * rh)  # vert_wall(xR, yT, roomH) for each j
            wall |= (ys == k * rh) & (xs < 3 * rw)  # horz_wall(xL, yB, roomW) for each i
        return jnp.where(wall[..., None], jnp.asarray(WALL_CELL), jnp.asarray(EMPTY_CELL))

    def generate(self, key: jax.Array) -> State:
        w, h = self.width, self.height
        walls = self.doors()
        u_doors, u_agent, u_objects = jax.random.split(key, 3)
        u = jax.random.uniform(u_doors, (len(walls), 2))
        grid = self.layout()
        xs, ys = G.coords(w, h)
        for n, (vertical, fixed, low, high) in enumerate(walls):
            along = G.randint(u[n, 0], low, high)
            colour = G.randint(u[n, 1], 0, NUM_COLOURS)  # _rand_elem(COLOR_NAMES)
            cell = (fixed, along) if vertical else (along, fixed)
            grid = G.put(grid, cell, G.cell(DOOR, colour, CLOSED))
        ua = jax.random.uniform(u_agent, (2,))
        agent = G.sample_cell(ua[0], G.is_empty(grid))  # place_agent(): any empty cell
        direction = G.randint(ua[1], 0, 4)
        not_agent = ~((xs == agent[0]) & (ys == agent[1]))

        def place(grid, u_i):
            # objType = _rand_elem(types); objColor = _rand_elem(COLOR_NAMES)
            kind = G.select(G.randint(u_i[0], 0, len(TYPES)), jnp.asarray(TYPES, jnp.int32))
            colour = G.randint(u_i[1], 0, NUM_COLOURS)
            # place_obj(obj): an empty cell that is not the agent's
            cell = G.sample_cell(u_i[2], G.is_empty(grid) & not_agent)
            return G.put(grid, cell, G.cell(kind, colour)), None

        uo = jax.random.uniform(u_objects, (NUM_OBJECTS, 3))
        grid, _ = jax.lax.scan(place, grid, uo)
        return self.init_state(grid, agent, direction, key)


IDS: dict[str, Callable[[], Environment]] = {
    # PlaygroundEnv(max_steps=100): 19 x 19.
    "MiniGrid-Playground-v0": lambda: Playground(width=19, height=19, max_steps=100),
}
