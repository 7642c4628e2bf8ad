"""``jaxgrid.wrappers``: the batched auto-reset equals ``vmap(AutoReset)`` bit for bit, and
``masked_map`` equals computing every row and selecting."""

from __future__ import annotations

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

import jaxgrid
from jaxgrid.wrappers import AutoReset, BatchedAutoReset, masked_map

NUM_ENVS = 24
# Test-only programs compile without LLVM's optimisations: same semantics, less compile time.
fast_jit = functools.partial(jax.jit, compiler_options={"xla_backend_optimization_level": 0})


@pytest.mark.parametrize(
    "env_id", ["TwoRooms-v0", pytest.param("ThreeRoomsKey-v0", marks=pytest.mark.slow)]
)
def test_batched_auto_reset_equals_vmapped_auto_reset(env_id):
    """Same states and time steps through many resets, all envs truncating together (more
    ended episodes in one step than one masked chunk) included."""
    base = jaxgrid.make(env_id, max_steps=12)  # short episodes: many resets, all envs at once
    single, batched = AutoReset(base), BatchedAutoReset(base)
    keys = jax.random.split(jax.random.PRNGKey(0), NUM_ENVS)
    states, first = fast_jit(batched.reset)(keys)
    ref_states, ref_first = fast_jit(jax.vmap(single.reset))(keys)
    chex.assert_trees_all_equal((states, first), (ref_states, ref_first))

    def run(step):
        def body(carry, key):
            actions = jax.random.randint(key, (NUM_ENVS,), 0, base.num_actions)
            new, ts = step(carry, actions)
            return new, (new, ts)

        keys = jax.random.split(jax.random.PRNGKey(1), 3 * base.max_steps)
        return lax.scan(body, states, keys)[1]

    ours = fast_jit(lambda: run(batched.step))()
    reference = fast_jit(lambda: run(jax.vmap(single.step)))()
    dones = np.asarray(ours[1].terminated | ours[1].truncated)
    assert dones.sum(1).max() > 16 and dones.sum() >= NUM_ENVS  # several chunks; every env
    chex.assert_trees_all_equal(ours, reference)


def test_batched_auto_reset_reads_static_settings_through():
    env = BatchedAutoReset(jaxgrid.make("TwoRooms-v0"))
    assert (env.view_size, env.num_actions) == (5, 7)
    assert hash(env) == hash(BatchedAutoReset(jaxgrid.make("TwoRooms-v0")))


def _row_fn(x):
    return jnp.tanh(x @ jnp.arange(12.0).reshape(3, 4) / 7.0) + x.sum(-1, keepdims=True)


@pytest.mark.parametrize("masked", [0, 3, 37, 40])
def test_masked_map_equals_the_dense_selection(masked):
    """No row, a few rows, more rows than one chunk (three passes of 16), every row."""
    rng = np.random.default_rng(masked)
    mask = np.zeros(40, bool)
    mask[rng.permutation(40)[:masked]] = True
    inputs = jnp.asarray(rng.normal(size=(40, 3)), jnp.float32)
    other = jnp.asarray(rng.normal(size=(40, 4)), jnp.float32)
    dense = jnp.where(mask[:, None], _row_fn(inputs), other)
    sparse = jax.jit(functools.partial(masked_map, fn=_row_fn))(mask, inputs=inputs, other=other)
    np.testing.assert_allclose(sparse, dense, rtol=1e-6)
    np.testing.assert_array_equal(sparse[~mask], other[~mask])


def test_masked_map_under_vmap_and_uses_only_masked_rows():
    rng = np.random.default_rng(0)
    masks = rng.random((3, 20)) < 0.3
    inputs = jnp.asarray(rng.normal(size=(3, 20, 3)), jnp.float32)
    other = jnp.zeros((3, 20, 4), jnp.float32)
    # Values in (1, 3): a matmul's rows may round differently in the last place for another
    # number of rows (masked_map's contract), which no value near 0 should magnify.
    fn = lambda x: jnp.tanh(x @ jnp.arange(12.0).reshape(3, 4) / 7.0) + 2.0  # noqa: E731
    batched = jax.jit(jax.vmap(lambda m, i, o: masked_map(m, fn, i, o)))(masks, inputs, other)
    dense = jnp.where(masks[..., None], fn(inputs), other)
    np.testing.assert_allclose(batched, dense, rtol=1e-6)

    def loud(x):  # an unmasked row's result placed in the output would show as NaN
        return jnp.where(jnp.isfinite(x).all(-1, keepdims=True), _row_fn(x), jnp.nan)

    poisoned = inputs[0].at[~masks[0]].set(jnp.nan)
    out = masked_map(jnp.asarray(masks[0]), loud, poisoned, other[0])
    assert np.isfinite(np.asarray(out)).all()
