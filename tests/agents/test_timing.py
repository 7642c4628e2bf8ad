"""agents.timing: compile ahead (timed apart), then block_until_ready timings."""

import chex
import jax
import jax.numpy as jnp
import pytest

from agents.timing import Timing, compile_ahead, measure, timed


def test_measure_compiles_once_and_times_each_call():
    @chex.assert_max_traces(n=1)
    def f(x):
        return jnp.cumsum(x * 2.0)

    x = jnp.arange(4.0)
    t = measure(f, x, repeats=3)
    assert len(t.times_s) == 3 and all(s > 0 for s in t.times_s)
    assert t.compile_s > 0
    assert t.best_s == min(t.times_s) <= t.median_s <= max(t.times_s)
    assert t.rate(10.0) == pytest.approx(10.0 / t.median_s)
    chex.assert_trees_all_equal(t.output, jnp.array([0.0, 2.0, 6.0, 12.0]))


def test_timing_median_and_best():
    t = Timing(compile_s=1.0, times_s=(3.0, 1.0, 2.0, 10.0))
    assert (t.median_s, t.best_s, t.rate(5.0)) == (2.5, 1.0, 2.0)


def test_compile_ahead_accepts_jitted_and_jit_options():
    compiled, seconds = compile_ahead(jax.jit(lambda x: x + 1), jnp.zeros(3))
    assert seconds > 0 and compiled(jnp.ones(3)).tolist() == [2.0, 2.0, 2.0]
    compiled, _ = compile_ahead(lambda x, n: x * n, jnp.ones(2), 3, static_argnums=1)
    assert compiled(jnp.ones(2)).tolist() == [3.0, 3.0]  # static n baked in
    with pytest.raises(ValueError, match="already jitted"):
        compile_ahead(jax.jit(lambda x: x), jnp.zeros(1), donate_argnums=0)


def test_timed_threads_donated_state():
    compiled, _ = compile_ahead(lambda s: s + 1, jnp.zeros(3), donate_argnums=0)
    state = jnp.zeros(3)
    for _ in range(3):
        state, dt = timed(compiled, state)
        assert dt > 0
    assert state.tolist() == [3.0, 3.0, 3.0]


def test_measure_rejects_bad_repeats_and_donation():
    with pytest.raises(ValueError, match="repeats"):
        measure(lambda x: x, jnp.zeros(1), repeats=0)
    with pytest.raises(ValueError, match="donate"):
        measure(lambda x: x, jnp.zeros(1), donate_argnums=0)
