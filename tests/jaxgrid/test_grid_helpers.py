"""The small array helpers of ``jaxgrid.grid`` that generators share.

* ``prefix_sum`` is ``jnp.cumsum`` exactly, alone and under ``vmap``.
* ``counter_uniforms`` is a documented function of the key: block ``b`` of a threefry key is
  the Threefry-2x32 hash of counters ``(b, 0 .. size/2)``, mapped to ``[0, 1)`` through the
  top 23 bits; typed and raw keys give the same numbers; blocks are independent draws
  (uniform marginals and no correlation between blocks, tested at fixed seeds); keys of
  another PRNG implementation fall back to ``uniform(fold_in(key, block))``.
* MultiRoom's reset hashes its key in two places only (the reset's split and one counter
  block per round of attempts): each hash site is a large fused kernel that XLA compiles on
  its own, which is what keeps the level's compile time within budget.
"""

from __future__ import annotations

import jax
import jax.extend.random as jxr
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

import jaxgrid
from jaxgrid import grid as G


@pytest.mark.parametrize("n", [1, 2, 7, 25])
def test_prefix_sum_is_cumsum(n):
    x = np.random.default_rng(n).integers(-5, 50, (6, n)).astype(np.int32)
    np.testing.assert_array_equal(G.prefix_sum(jnp.asarray(x[0])), np.cumsum(x[0]))
    np.testing.assert_array_equal(jax.vmap(G.prefix_sum)(jnp.asarray(x)), np.cumsum(x, axis=1))
    assert G.prefix_sum(jnp.asarray(x[0])).dtype == jnp.int32


def _expected_uniforms(pair, block, size):
    half = (size + 1) // 2
    counters = np.concatenate([np.full(half, block, np.uint32), np.arange(half, dtype=np.uint32)])
    bits = np.asarray(jxr.threefry_2x32(jnp.asarray(pair, jnp.uint32), jnp.asarray(counters)))
    bits = bits[:size]
    return ((bits >> 9) | np.uint32(0x3F800000)).view(np.float32) - np.float32(1.0)


@pytest.mark.parametrize("shape", [(1,), (5,), (4, 7)])
def test_counter_uniforms_are_the_documented_hash(shape):
    raw = jax.random.PRNGKey(42)
    got = np.asarray(G.counter_uniforms(raw, 3, shape))
    assert got.shape == shape and got.dtype == np.float32
    size = int(np.prod(shape))
    np.testing.assert_array_equal(got.ravel(), _expected_uniforms(np.asarray(raw), 3, size))
    typed = jax.random.wrap_key_data(raw)
    np.testing.assert_array_equal(np.asarray(G.counter_uniforms(typed, 3, shape)), got)


def test_counter_uniforms_jit_and_traced_block():
    key = jax.random.PRNGKey(7)
    f = jax.jit(lambda k, b: G.counter_uniforms(k, b, (6,)))
    for block in (0, 1, 1000):
        np.testing.assert_array_equal(
            np.asarray(f(key, jnp.int32(block))),
            np.asarray(G.counter_uniforms(key, block, (6,))),
        )


def test_counter_uniform_blocks_are_uniform_and_uncorrelated():
    keys = jax.random.split(jax.random.PRNGKey(0), 4000)
    draw = jax.vmap(lambda k: jnp.stack([G.counter_uniforms(k, b, (3,)) for b in range(3)]))
    u = np.asarray(draw(keys))  # (keys, block, index)
    assert u.min() >= 0.0 and u.max() < 1.0
    for block in range(3):
        for index in range(3):
            assert stats.kstest(u[:, block, index], "uniform").pvalue > 1e-3
    # distinct blocks and distinct indices of one key are uncorrelated
    flat = u.reshape(len(keys), -1)
    corr = np.corrcoef(flat, rowvar=False)
    off = corr[~np.eye(corr.shape[0], dtype=bool)]
    assert np.abs(off).max() < 0.07  # 4000 samples: sd 0.016, so 4.4 sd over 72 pairs


def test_counter_uniforms_other_prng_falls_back_to_fold_in():
    key = jax.random.key(3, impl="rbg")
    got = np.asarray(G.counter_uniforms(key, 2, (4,)))
    want = np.asarray(jax.random.uniform(jax.random.fold_in(key, 2), (4,)))
    np.testing.assert_array_equal(got, want)


def _sub_jaxprs(params):
    for value in params.values():
        for item in value if isinstance(value, (tuple, list)) else (value,):
            if isinstance(item, jax.extend.core.ClosedJaxpr):
                yield item.jaxpr
            elif isinstance(item, jax.extend.core.Jaxpr):
                yield item


# the primitives that hash a key: a split, fold_in or bits of a typed key, or a raw Threefry
HASHES = {"random_split", "random_fold_in", "random_bits", "threefry2x32"}


def _hash_sites(jaxpr) -> int:
    """Key hashes in ``jaxpr``, nested calls and loops included (each body once)."""
    count = 0
    for eqn in jaxpr.eqns:
        count += eqn.primitive.name in HASHES
        count += sum(_hash_sites(sub) for sub in _sub_jaxprs(eqn.params))
    return count


def test_multiroom_reset_hashes_in_two_places():
    env = jaxgrid.make("MiniGrid-MultiRoom-N6-v0")
    jaxpr = jax.make_jaxpr(env.reset)(jax.random.PRNGKey(0)).jaxpr
    assert _hash_sites(jaxpr) == 2
