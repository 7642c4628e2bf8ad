"""Pure helpers that build and query grids (uint8 ``(W, H, 3)``, indexed ``[x, y]``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrid.constants import EMPTY, EMPTY_CELL, WALL_CELL


def room(width: int, height: int) -> np.ndarray:
    """Empty room enclosed by grey walls (``Grid.wall_rect(0, 0, w, h)``), as a numpy constant."""
    grid = np.broadcast_to(EMPTY_CELL, (width, height, 3)).copy()
    grid[0, :] = grid[-1, :] = WALL_CELL
    grid[:, 0] = grid[:, -1] = WALL_CELL
    return grid


def cell(kind: int, colour: int = 0, state: int = 0) -> jax.Array:
    """uint8 ``(3,)`` cell encoding (arguments may be traced)."""
    return jnp.stack([jnp.asarray(kind), jnp.asarray(colour), jnp.asarray(state)]).astype(
        jnp.uint8
    )


def coords(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """``(xs, ys)`` integer coordinate planes of shape ``(W, H)``."""
    return np.meshgrid(np.arange(width), np.arange(height), indexing="ij")


def is_empty(grid: jax.Array) -> jax.Array:
    """bool ``(W, H)``: cells holding no object."""
    return grid[..., 0] == EMPTY


def sample_cell(key: jax.Array, allowed: jax.Array) -> jax.Array:
    """Uniform ``(x, y)`` among the ``True`` cells of ``allowed`` (``(W, H)`` bool).

    MiniGrid's ``place_obj`` rejection-samples uniformly over a rectangle until it hits a valid
    cell; that is exactly the uniform distribution over valid cells, which an argmax of
    masked uniform noise draws in one shot. ``allowed`` must contain at least one cell.
    """
    height = allowed.shape[1]
    noise = jax.random.uniform(key, allowed.shape)
    flat = jnp.argmax(jnp.where(allowed, noise, -1.0).reshape(-1))
    return jnp.stack([flat // height, flat % height]).astype(jnp.int32)


def put(grid: jax.Array, pos: jax.Array, value) -> jax.Array:
    """``grid`` with ``grid[pos] = value`` (scatter; meant for reset-time layout building)."""
    return grid.at[pos[0], pos[1]].set(jnp.asarray(value, dtype=grid.dtype))
