"""Pure helpers that build and query grids (uint8 ``(W, H, 3)``, indexed ``[x, y]``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.random import threefry_2x32

from jaxgrid.constants import EMPTY, EMPTY_CELL, WALL_CELL


def room(width: int, height: int) -> np.ndarray:
    """Empty room enclosed by grey walls (``Grid.wall_rect(0, 0, w, h)``), as a numpy constant."""
    grid = np.broadcast_to(EMPTY_CELL, (width, height, 3)).copy()
    grid[0, :] = grid[-1, :] = WALL_CELL
    grid[:, 0] = grid[:, -1] = WALL_CELL
    return grid


def cell(kind: int, colour: int = 0, state: int = 0) -> jax.Array:
    """uint8 ``(3,)`` cell encoding (arguments may be traced)."""
    return jnp.stack([jnp.asarray(kind), jnp.asarray(colour), jnp.asarray(state)]).astype(jnp.uint8)


def coords(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """``(xs, ys)`` integer coordinate planes of shape ``(W, H)``."""
    return np.meshgrid(np.arange(width), np.arange(height), indexing="ij")


def is_empty(grid: jax.Array) -> jax.Array:
    """bool ``(W, H)``: cells holding no object."""
    return grid[..., 0] == EMPTY


def randint(u: jax.Array, low, high) -> jax.Array:
    """Integer in ``[low, high)`` from a uniform ``u`` in ``[0, 1)`` (MiniGrid's ``_rand_int``)."""
    n = high - low
    return low + jnp.minimum(jnp.floor(u * n).astype(jnp.int32), n - 1)


def distinct(u: jax.Array, values, n: int) -> jax.Array:
    """``n`` distinct entries of ``values``, uniformly, from uniforms ``u`` (at least ``n``):
    a partial Fisher-Yates shuffle, ``n`` static (a few draws: the loop unrolls)."""
    pool = jnp.asarray(values)
    out = []
    for i in range(n):
        k = randint(u[i], i, len(values))
        pi, pk = pool[i], pool[k]
        pool = pool.at[i].set(pk).at[k].set(pi)
        out.append(pool[i])
    return jnp.stack(out)


def select(index, table) -> jax.Array:
    """``table[index]`` along the first axis as a select-sum: no gather under ``vmap``, where
    a gather with a traced index is slow on CPU and the tables are a few rows."""
    table = jnp.asarray(table)
    hit = jnp.arange(table.shape[0]) == index
    return jnp.sum(jnp.where(hit.reshape((-1,) + (1,) * (table.ndim - 1)), table, 0), axis=0)


def prefix_sum(x: jax.Array) -> jax.Array:
    """``jnp.cumsum(x)`` of a short 1-D integer array, as one masked sum over a triangle.

    XLA's CPU backend lowers ``cumsum`` to a pad, a reduce-window and a slice, each a kernel
    compiled on its own; the triangle is one fused reduction. Exact for integers; ``O(n^2)``
    work, for the handful of entries of a grid axis.
    """
    n = x.shape[-1]
    lower = np.arange(n)[:, None] >= np.arange(n)[None, :]  # lower[i, j]: j <= i
    return jnp.sum(jnp.where(lower, x[..., None, :], 0), axis=-1, dtype=x.dtype)


def sample_cell(u: jax.Array, allowed: jax.Array) -> jax.Array:
    """Uniform ``(x, y)`` among the ``True`` cells of ``allowed`` (``(W, H)`` bool), from ``u``.

    MiniGrid's ``place_obj`` rejection-samples a rectangle until it hits a valid cell, which
    is the uniform distribution over valid cells. We pick the ``floor(u * count)``-th valid
    cell in two levels (column, then row): two short prefix sums instead of one noise draw per
    cell, since random bits dominate the cost of a reset. ``allowed`` must not be all False.
    """
    counts = jnp.sum(allowed, axis=1, dtype=jnp.int32)  # valid cells per column x
    cum = prefix_sum(counts)
    r = jnp.minimum(jnp.floor(u * cum[-1]).astype(jnp.int32), cum[-1] - 1)
    x = jnp.argmax(cum > r)
    r = r - (cum[x] - counts[x])
    column = jnp.sum(  # allowed[x] as a select-sum: no gather under vmap
        jnp.where((jnp.arange(allowed.shape[0]) == x)[:, None], allowed, False),
        axis=0,
        dtype=jnp.int32,
    )
    y = jnp.argmax(prefix_sum(column) > r)
    return jnp.stack([x, y]).astype(jnp.int32)


def at(shape: tuple[int, int], pos) -> jax.Array:
    """bool ``(W, H)``, True at ``pos`` only."""
    xs, ys = coords(*shape)
    return (xs == pos[0]) & (ys == pos[1])


def put(grid: jax.Array, pos, value) -> jax.Array:
    """``grid`` with ``grid[pos] = value``.

    A select over the whole grid rather than a scatter: scatters under ``vmap`` are slow on
    CPU and a grid is only a few hundred bytes.
    """
    value = jnp.asarray(value, dtype=grid.dtype)
    return jnp.where(at(grid.shape[:2], pos)[..., None], value, grid)


def counter_uniforms(key: jax.Array, block, shape: tuple[int, ...]) -> jax.Array:
    """Uniforms in ``[0, 1)`` of ``shape``: block ``block`` of ``key``'s counter stream.

    Blocks ``0, 1, 2, ...`` of one key are independent draws, each one Threefry hash of
    counters ``(block, 0 .. size / 2)``: a loop that needs fresh numbers per iteration
    hashes once per iteration instead of folding the iteration into the key first, and
    every hash site costs compile time (about 0.2-0.5 s each on CPU). Keys of another PRNG
    implementation fall back to ``uniform(fold_in(key, block))``.
    """
    typed = jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
    impl = jax.random.key_impl(key) if typed else None
    if typed and str(impl) != "threefry2x32":
        return jax.random.uniform(jax.random.fold_in(key, block), shape)
    pair = jax.random.key_data(key) if typed else key
    size = int(np.prod(shape))
    half = (size + 1) // 2  # each counter pair hashes to two words
    hi = jnp.broadcast_to(jnp.asarray(block, jnp.uint32), (half,))
    lo = jnp.arange(half, dtype=jnp.uint32)
    bits = threefry_2x32(pair, jnp.concatenate([hi, lo]))[:size]
    mantissa = (bits >> 9) | np.uint32(0x3F800000)
    return (jax.lax.bitcast_convert_type(mantissa, jnp.float32) - 1.0).reshape(shape)
