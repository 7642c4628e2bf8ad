"""MiniGrid's transition function (``MiniGridEnv.step`` of minigrid 3.2.0) as pure JAX.

Every action is computed branch-free with ``jnp.where``: under ``vmap`` a ``lax.switch`` over
actions would evaluate every branch anyway, and these are a handful of scalar ops. An action
outside ``0..6`` matches no branch and therefore acts as ``done`` (a no-op).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxgrid.constants import (
    BALL,
    BOX,
    CLOSED,
    DIR_TO_VEC,
    DOOR,
    DROP,
    EMPTY,
    EMPTY_CELL,
    FLOOR,
    FORWARD,
    GOAL,
    KEY,
    LAVA,
    LEFT,
    LOCKED,
    OPEN,
    PICKUP,
    RIGHT,
    TOGGLE,
    WALL_CELL,
)
from jaxgrid.types import State


def front_pos(state: State) -> jax.Array:
    """``(x, y)`` of the cell the agent faces."""
    return state.agent_pos + jnp.asarray(DIR_TO_VEC)[state.agent_dir]


def get_cell(grid: jax.Array, pos: jax.Array) -> jax.Array:
    """Encoding of ``grid[pos]``; a grey wall outside the grid."""
    width, height = grid.shape[:2]
    x, y = pos[0], pos[1]
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    cell = grid[jnp.clip(x, 0, width - 1), jnp.clip(y, 0, height - 1)]
    return jnp.where(inside, cell, jnp.asarray(WALL_CELL))


def set_cell(grid: jax.Array, pos: jax.Array, cell: jax.Array, when: jax.Array) -> jax.Array:
    """``grid`` with ``grid[pos] = cell`` where ``when``; positions outside the grid are ignored.

    A full-grid select rather than a scatter: under ``vmap`` on CPU it fuses with the rest of
    the step and costs ``W * H * 3`` byte selects.
    """
    width, height = grid.shape[:2]
    hit = (jnp.arange(width)[:, None] == pos[0]) & (jnp.arange(height)[None, :] == pos[1])
    return jnp.where((hit & when)[..., None], cell.astype(grid.dtype), grid)


def transition(state: State, action: jax.Array, max_steps: int):
    """One MiniGrid step without the observation.

    Returns ``(state, reward, terminated, truncated)``; ``reward`` is float32,
    ``1 - 0.9 * step_count / max_steps`` on reaching the goal, else 0.
    """
    action = jnp.asarray(action, jnp.int32)
    step_count = state.step_count + 1
    fwd = front_pos(state)
    cell = get_cell(state.grid, fwd)
    kind, colour, door_state = cell[0], cell[1], cell[2]
    carrying = state.carrying
    hands_empty = carrying[0] == EMPTY

    turn = jnp.where(action == LEFT, -1, jnp.where(action == RIGHT, 1, 0))
    agent_dir = (state.agent_dir + turn) % 4

    is_door = kind == DOOR
    can_overlap = (
        (kind == EMPTY)
        | (kind == GOAL)
        | (kind == LAVA)
        | (kind == FLOOR)
        | (is_door & (door_state == OPEN))
    )
    forward = action == FORWARD
    agent_pos = jnp.where(forward & can_overlap, fwd, state.agent_pos)
    reached_goal = forward & (kind == GOAL)
    terminated = reached_goal | (forward & (kind == LAVA))

    pickup = (action == PICKUP) & hands_empty & ((kind == KEY) | (kind == BALL) | (kind == BOX))
    drop = (action == DROP) & ~hands_empty & (kind == EMPTY)
    toggle = action == TOGGLE
    unlock = (
        toggle & is_door & (door_state == LOCKED) & (carrying[0] == KEY) & (carrying[1] == colour)
    )
    flip = toggle & is_door & (door_state != LOCKED)
    open_box = toggle & (kind == BOX)  # an empty box vanishes when opened (MiniGrid Box.toggle)

    new_door_state = jnp.where(unlock | (flip & (door_state == CLOSED)), OPEN, CLOSED)
    door_cell = jnp.stack([kind, colour, new_door_state.astype(cell.dtype)])
    new_cell = jnp.where(
        pickup | open_box, jnp.asarray(EMPTY_CELL), jnp.where(drop, carrying, door_cell)
    )
    grid = set_cell(state.grid, fwd, new_cell, pickup | drop | unlock | flip | open_box)
    carrying = jnp.where(pickup, cell, jnp.where(drop, jnp.asarray(EMPTY_CELL), carrying))

    reward = jnp.where(
        reached_goal, 1.0 - 0.9 * (step_count.astype(jnp.float32) / max_steps), 0.0
    ).astype(jnp.float32)
    truncated = step_count >= max_steps
    new_state = state.replace(
        grid=grid,
        agent_pos=agent_pos,
        agent_dir=agent_dir,
        carrying=carrying,
        step_count=step_count,
    )
    return new_state, reward, terminated, truncated
