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


@functools.cache
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
    """Un-occluded ``(V, V, 3)`` window of ``grid`` in the agent's frame (outside = grey wall)."""
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


# Views up to this size use a lookup table of every (seeds, transparent) row pair
# (2**(2V) int32 entries: 64 KiB at V=7, 1 MiB at V=9): one small gather per row instead of
# ~30 dependent shifts, about 4x faster on CPU.
LUT_MAX_VIEW = 9


def _fill(seeds, transparent, shift, size: int):
    """Spread ``seeds`` (a row as bits) in ``shift``'s direction through transparent cells.

    A cell passes visibility on to its neighbour only if it is itself transparent, so the
    neighbour's "door" is ``shift(transparent, 1)``; log-step (Kogge-Stone) doubling covers a
    row of ``size`` cells in ``ceil(log2(size))`` steps. Works on numpy and JAX integers.
    """
    gen, pro = seeds, shift(transparent, 1)
    k = 1
    while k < size:
        gen = gen | (pro & shift(gen, k))
        pro = pro & shift(pro, k)
        k *= 2
    return gen


def _row_update(seeds, transparent, size: int):
    """One row of ``process_vis``: ``(visible bits of this row, seeds of the row above)``.

    The quirks are kept because MiniGrid has them: the left-to-right pass never starts from the
    last column and the right-to-left pass never from the first, so the first column lights
    the row above only if it was reached in the left-to-right pass.
    """
    full = (1 << size) - 1
    to_right = lambda x, k: (x << k) & full  # column i -> i + k
    to_left = lambda x, k: x >> k  # column i -> i - k
    left = _fill(seeds, transparent, to_right, size)
    right = _fill(left, transparent, to_left, size)
    lit_left = left & transparent & (full >> 1)  # left pass visits columns 0 .. V-2
    lit_right = right & transparent & (full - 1)  # right pass visits columns 1 .. V-1
    return right, (lit_left | (lit_left << 1) | lit_right | (lit_right >> 1)) & full


@functools.cache
def _row_table(size: int) -> np.ndarray:
    """int32 ``(2**(2V),)``: entry ``seeds << V | transparent`` packs ``_row_update``'s
    ``visible | next_seeds << V``."""
    seeds = np.arange(1 << size, dtype=np.int64)[:, None]
    transparent = np.arange(1 << size, dtype=np.int64)[None, :]
    visible, above = _row_update(seeds, transparent, size)
    return (visible | (above << size)).astype(np.int32).reshape(-1)


def visibility_mask(transparent: jax.Array) -> jax.Array:
    """Exact replica of ``minigrid.core.grid.Grid.process_vis`` on a ``(V, V)`` view.

    MiniGrid sweeps rows from the agent's row (``j = V - 1``) upwards; in each row a
    left-to-right pass then a right-to-left pass spread visibility sideways out of transparent
    visible cells, and each transparent visible cell lights itself and its diagonal neighbours
    in the row above. We hold each row as the bits of one int32 (bit ``i`` = column ``i``) and
    update it by table lookup (or bit shifts for large views). The loop over rows is over the
    static view size.
    """
    v = transparent.shape[0]
    weights = jnp.asarray(1 << np.arange(v), jnp.int32)
    rows_t = jnp.sum(jnp.where(transparent, weights[:, None], 0), axis=0)  # (V,), row j's bits
    table = jnp.asarray(_row_table(v)) if v <= LUT_MAX_VIEW else None
    seeds = jnp.int32(1 << (v // 2))  # the agent's cell
    rows = [None] * v
    for j in reversed(range(v)):
        if table is not None:
            entry = table[(seeds << v) | rows_t[j]]
            rows[j], seeds = entry & ((1 << v) - 1), entry >> v
        else:
            rows[j], seeds = _row_update(seeds, rows_t[j], v)
    bits = jnp.stack(rows)  # (V,) indexed j
    return ((bits[None, :] >> jnp.arange(v, dtype=jnp.int32)[:, None]) & 1).astype(bool)


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
    # The agent's own cell shows what it carries ((1, 0, 0), empty, when nothing). A select
    # with a constant mask, not a scatter: scatters under vmap are slow on CPU.
    agent_cell = np.zeros((view_size, view_size, 1), bool)
    agent_cell[view_size // 2, view_size - 1] = True
    return jnp.where(agent_cell, carrying, cells)
