"""MiniGrid's Dynamic-Obstacles levels, generated natively, with their moving balls.

``generate`` mirrors ``DynamicObstaclesEnv._gen_grid``; the comments quote the MiniGrid call
each line reproduces. ``place_agent``/``place_obj`` rejection-sample a cell; here the cell is
drawn directly from the uniform distribution over the cells they accept.

``DynamicObstaclesEnv.step`` is reproduced by :meth:`DynamicObstacles.step`:

1. an action outside ``0..2`` (left, right, forward) becomes ``left`` (MiniGrid does so for
   ``action >= 3`` and raises on negative ones);
2. ``not_clear``: the cell ahead holds anything but the goal (walls and balls alike), read
   before the balls move;
3. each ball in turn moves to a uniform cell of the 3 x 3 block around it that is empty and
   not the agent's (its own cell is occupied, so a ball that can move does), seeing the
   balls moved before it; a ball with no such cell stays;
4. ``MiniGridEnv.step`` with the action;
5. ``forward`` with ``not_clear`` ends the episode with reward -1.

MiniGrid's step 3 is ``place_obj(..., max_tries=100)``, which gives up (the ball stays) after
101 rejected proposals even when a free cell exists: at most ``(8/9) ** 101 < 7e-6`` per ball
and step, when a single cell of the nine is free. That failure is not reproduced; otherwise
the move's distribution is MiniGrid's. The balls' cells are kept in ``state.extras``
(int32 ``(n, 2)``, MiniGrid's order of ``self.obstacles``), and the moves are drawn from
``state.key``, so ``step`` stays a pure function of ``(state, action)``.
:meth:`DynamicObstacles.step_after_moves` takes the moved grid instead, for replaying
MiniGrid's own moves. :data:`IDS` maps MiniGrid's ids, with its per-id defaults, to factories.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import grid as G
from jaxgrid.constants import BALL, BLUE, EMPTY, EMPTY_CELL, FORWARD, GOAL, GOAL_CELL, LEFT
from jaxgrid.contents import Contents
from jaxgrid.dynamics import front_pos, get_cell, transition
from jaxgrid.environment import Environment, check_action
from jaxgrid.types import State, TimeStep

NUM_ACTIONS = 3  # action_space = Discrete(self.actions.forward + 1)
BALL_CELL = np.array([BALL, BLUE, 0], np.uint8)  # Ball(): blue


def obstacle_count(size: int, n_obstacles: int) -> int:
    """``DynamicObstaclesEnv``'s own reduction: ``n`` if ``n <= size / 2 + 1``, else
    ``int(size / 2)``."""
    return int(n_obstacles) if n_obstacles <= size / 2 + 1 else int(size / 2)


class DynamicObstacles(Environment):
    """``DynamicObstaclesEnv``: reach the goal in the bottom-right corner among balls that
    move at every step; touching a ball or a wall (``forward`` into it) ends the episode with
    reward -1. See the module docstring for the step.

    The goal is at ``(width - 2, height - 2)``; the agent starts at ``agent_start`` facing
    ``agent_start_dir``, or with ``agent_start=None`` on a uniform empty cell with a uniform
    direction; then each of the ``n_obstacles`` balls lies on a uniform empty cell that is
    not the agent's. ``n_obstacles`` is the count after MiniGrid's reduction
    (:func:`obstacle_count`), which the registered ids apply. Three actions.
    """

    n_obstacles: int = struct.field(pytree_node=False, default=4)
    agent_start: tuple[int, int] | None = struct.field(pytree_node=False, default=(1, 1))
    agent_start_dir: int = struct.field(pytree_node=False, default=0)

    def __post_init__(self):
        n = self.n_obstacles
        if not isinstance(n, int) or isinstance(n, bool) or n < 0:
            raise ValueError(f"DynamicObstacles.n_obstacles must be an int >= 0, got {n!r}")
        super().__post_init__()
        if self.agent_start is not None:
            x, y = self.agent_start
            if not (1 <= x < self.width - 1 and 1 <= y < self.height - 1) or (x, y) == (
                self.width - 2,
                self.height - 2,
            ):
                raise ValueError(
                    f"DynamicObstacles.agent_start {self.agent_start} must be inside the walls "
                    "and not the goal's cell"
                )
        if self.agent_start_dir not in (0, 1, 2, 3):
            raise ValueError(
                f"DynamicObstacles.agent_start_dir must be 0..3, got {self.agent_start_dir!r}"
            )

    def min_size(self):
        side = 4  # the agent's cell, the goal's and each ball's inside the walls
        while (side - 2) ** 2 - 2 < self.n_obstacles:
            side += 1
        return side, side, f"the agent, the goal and {self.n_obstacles} balls inside the walls"

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    def contents(self) -> Contents:
        return Contents(ball={"blue"} if self.n_obstacles else ())

    def generate(self, key: jax.Array) -> State:
        w, h = self.width, self.height
        u = jax.random.uniform(key, (2 + self.n_obstacles,))
        # grid.wall_rect(0, 0, width, height); grid.set(width - 2, height - 2, Goal())
        grid = G.put(jnp.asarray(G.room(w, h)), (w - 2, h - 2), GOAL_CELL)
        if self.agent_start is None:  # place_agent(): any empty cell, _rand_int(0, 4)
            agent = G.sample_cell(u[0], G.is_empty(grid))
            direction = G.randint(u[1], 0, 4)
        else:
            agent = jnp.asarray(self.agent_start, jnp.int32)
            direction = jnp.int32(self.agent_start_dir)
        xs, ys = G.coords(w, h)
        not_agent = ~((xs == agent[0]) & (ys == agent[1]))

        def place(grid, u_i):  # place_obj(Ball(), max_tries=100): empty, not the agent's
            cell = G.sample_cell(u_i, G.is_empty(grid) & not_agent)
            return G.put(grid, cell, BALL_CELL), cell

        grid, cells = jax.lax.scan(place, grid, u[2:])
        cells = cells.reshape(self.n_obstacles, 2).astype(jnp.int32)
        return self.init_state(grid, agent, direction, key, cells)

    def allowed(self, grid: jax.Array, cell: jax.Array, agent: jax.Array) -> jax.Array:
        """bool ``(W, H)``: where the ball at ``cell`` may move, ``place_obj(top=cell - 1,
        size=(3, 3))``'s accepted cells: empty and not the agent's."""
        xs, ys = G.coords(self.width, self.height)
        near = (jnp.abs(xs - cell[0]) <= 1) & (jnp.abs(ys - cell[1]) <= 1)
        return near & G.is_empty(grid) & ~((xs == agent[0]) & (ys == agent[1]))

    def move_obstacles(self, state: State, u: jax.Array) -> tuple[jax.Array, jax.Array]:
        """``(grid, cells)`` after every ball's move (step 3), from uniforms ``u`` ``(n,)``."""

        def move(grid, xs_i):
            cell, u_i = xs_i
            allowed = self.allowed(grid, cell, state.agent_pos)
            can = jnp.any(allowed)
            new = jnp.where(can, G.sample_cell(u_i, allowed | ~can), cell)
            # self.grid.set(*new, ball); self.grid.set(*old_pos, None), unless it stays
            grid = G.put(grid, cell, jnp.where(can, jnp.asarray(EMPTY_CELL), BALL_CELL))
            return G.put(grid, new, BALL_CELL), new

        grid, cells = jax.lax.scan(move, state.grid, (state.extras, u))
        return grid, cells.reshape(self.n_obstacles, 2)

    def step_after_moves(
        self, state: State, action: jax.Array, grid: jax.Array, cells: jax.Array
    ) -> tuple[State, TimeStep]:
        """The step from ``state`` with the balls already moved to ``grid``/``cells``."""
        check_action(action)
        action = jnp.asarray(action, jnp.int32)
        action = jnp.where((action >= 0) & (action < NUM_ACTIONS), action, LEFT)
        ahead = get_cell(state.grid, front_pos(state))[0]
        not_clear = (ahead != EMPTY) & (ahead != GOAL)  # front_cell and type != "goal"
        moved = state.replace(grid=grid, extras=cells)
        state, reward, terminated, truncated = transition(moved, action, self.max_steps)
        hit = (action == FORWARD) & not_clear
        reward = jnp.where(hit, -1.0, reward).astype(jnp.float32)
        return state, self.make_timestep(state, reward, terminated | hit, truncated)

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """``DynamicObstaclesEnv.step``: the balls move (drawn from ``state.key``), then the
        agent acts (see the module docstring)."""
        check_action(action)
        key, sub = jax.random.split(state.key)
        u = jax.random.uniform(sub, (self.n_obstacles,))
        grid, cells = self.move_obstacles(state, u)
        return self.step_after_moves(state.replace(key=key), action, grid, cells)


def _dynamic(size: int, n: int = 4, random_start: bool = False) -> Callable[[], Environment]:
    # DynamicObstaclesEnv(size, n_obstacles, agent_start_pos): max_steps 4 * size**2,
    # see_through_walls=True.
    return lambda: DynamicObstacles(
        width=size,
        height=size,
        max_steps=4 * size**2,
        see_through_walls=True,
        n_obstacles=obstacle_count(size, n),
        agent_start=None if random_start else (1, 1),
    )


IDS: dict[str, Callable[[], Environment]] = {
    "MiniGrid-Dynamic-Obstacles-5x5-v0": _dynamic(5, 2),
    "MiniGrid-Dynamic-Obstacles-Random-5x5-v0": _dynamic(5, 2, random_start=True),
    "MiniGrid-Dynamic-Obstacles-6x6-v0": _dynamic(6, 3),
    "MiniGrid-Dynamic-Obstacles-Random-6x6-v0": _dynamic(6, 3, random_start=True),
    "MiniGrid-Dynamic-Obstacles-8x8-v0": _dynamic(8),
    "MiniGrid-Dynamic-Obstacles-16x16-v0": _dynamic(16, 8),
}
