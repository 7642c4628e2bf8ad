"""MiniGrid's egocentric, partially observable view, computed without Python control flow.

MiniGrid builds the view by slicing a ``V x V`` window in front of the agent (cells outside the
grid read as grey walls), rotating it ``agent_dir + 1`` times so the agent sits at
``(V // 2, V - 1)`` facing up, running ``Grid.process_vis`` for occlusion, and finally writing
the carried object (or empty) into the agent's own cell. We compute the same thing with one
gather: every view cell ``(i, j)`` maps to the world cell
``agent_pos + forward * (V - 1 - j) + right * (i - V // 2)``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrid.constants import CLOSED, DIR_TO_VEC, DOOR, LOCKED, WALL, WALL_CELL


@functools.lru_cache(maxsize=None)
def view_offsets(view_size: int) -> np.ndarray:
    """int32 ``(4, V, V, 2)``: world offset of view cell ``[i, j]`` for each direction."""
    v = view_size
    i, j = np.meshgrid(np.arange(v), np.arange(v), indexing="ij")
    out = np.empty((4, v, v, 2), dtype=np.int32)
    for d, (fx, fy) in enumerate(DIR_TO_VEC):
        rx, ry = -fy, fx  # MiniGrid's right_vec
        ahead, side = v - 1 - j, i - v // 2
        out[d, ..., 0] = fx * ahead + rx * side
        out[d, ..., 1] = fy * ahead + ry * side
    return out


def view_cells(grid: jax.Array, agent_pos: jax.Array, agent_dir: jax.Array, view_size: int):
    """The un-occluded ``(V, V, 3)`` window of ``grid`` in the agent's frame (out of grid = wall)."""
    width, height = grid.shape[:2]
    xy = agent_pos + jnp.asarray(view_offsets(view_size))[agent_dir]  # (V, V, 2)
    x, y = xy[..., 0], xy[..., 1]
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    flat = jnp.clip(x, 0, width - 1) * height + jnp.clip(y, 0, height - 1)
    cells = grid.reshape(width * height, 3)[flat]
    return jnp.where(inside[..., None], cells, jnp.asarray(WALL_CELL))


def see_behind(cells: jax.Array) -> jax.Array:
    """Cells one can see past: anything but walls and doors that are not open."""
    kind, state = cells[..., 0], cells[..., 2]
    return (kind != WALL) & ~((kind == DOOR) & ((state == CLOSED) | (state == LOCKED)))


def visibility_mask(transparent: jax.Array) -> jax.Array:
    """Exact replica of ``minigrid.core.grid.Grid.process_vis`` on a ``(V, V)`` view.

    MiniGrid sweeps rows from the agent's row upwards; in each row a left-to-right pass then a
    right-to-left pass spread visibility sideways through transparent cells, and each
    transparent visible cell lights itself and its diagonal neighbours in the row above.
    The asymmetry is kept on purpose (the leftmost cell lights the row above only if it was
    reached in the left-to-right pass), because MiniGrid behaves that way. The loops run over
    the static view size (at most a few dozen tiny elementwise ops), not over data.
    """
    v = transparent.shape[0]
    rows = []
    carry = jnp.zeros((v,), bool).at[v // 2].set(True)  # row V-1 starts with the agent only
    for j in reversed(range(v)):
        t = transparent[:, j]
        left = [carry[0]]  # left-to-right pass
        for i in range(1, v):
            left.append(carry[i] | (left[i - 1] & t[i - 1]))
        right = [None] * v  # right-to-left pass
        right[v - 1] = left[v - 1]
        for i in reversed(range(v - 1)):
            right[i] = left[i] | (right[i + 1] & t[i + 1])
        rows.append(jnp.stack(right))
        if j == 0:
            break
        a = [left[i] & t[i] for i in range(v - 1)]  # lit during the left pass (i <= V-2)
        b = [None] + [right[i] & t[i] for i in range(1, v)]  # lit during the right pass
        up = []
        for k in range(v):
            lit = []
            if k <= v - 2:
                lit.append(a[k])
            if k >= 1:
                lit += [a[k - 1], b[k]]
            if k + 1 <= v - 1:
                lit.append(b[k + 1])
            up.append(functools.reduce(jnp.logical_or, lit))
        carry = jnp.stack(up)
    return jnp.stack(rows[::-1], axis=1)  # (V, V) indexed [i, j]


def egocentric_view(
    grid: jax.Array,
    agent_pos: jax.Array,
    agent_dir: jax.Array,
    carrying: jax.Array,
    view_size: int,
    see_through_walls: bool,
) -> jax.Array:
    """MiniGrid's ``obs["image"]``: uint8 ``(V, V, 3)`` indexed ``[x, y]``, hidden cells zero."""
    cells = view_cells(grid, agent_pos, agent_dir, view_size)
    if not see_through_walls:
        visible = visibility_mask(see_behind(cells))
        cells = jnp.where(visible[..., None], cells, jnp.zeros_like(cells))
    # The agent's own cell shows what it carries ((1, 0, 0), empty, when nothing).
    return cells.at[view_size // 2, view_size - 1].set(carrying)
