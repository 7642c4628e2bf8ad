"""checker.reward: the on-device ring buffer (order, clearing at episode starts, across
auto-resets) and ``violation_prob``'s sentence-table path."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from helpers.checker_cases import TINY
from helpers.xla import CHEAP

import checker
from checker import TrainedChecker, init_buffer, push, violation_prob
from checker.reward import sentence_codes
from jaxgrid import language
from jaxgrid.language import sentence_table

# ------------------------------------------------------------------------------ ring buffer


def test_push_order_and_clearing():
    buf = init_buffer(2, 3, 5)
    assert buf.shape == (2, 3, 5, 5, 3) and buf.dtype == jnp.uint8
    frames = [np.full((2, 5, 5, 3), i + 1, np.uint8) for i in range(5)]
    starts = [[1, 1], [0, 0], [0, 1], [0, 0], [1, 0]]
    for f, s in zip(frames, starts, strict=True):
        buf = push(buf, f, jnp.asarray(s, bool))
    b = np.asarray(buf)[..., 0, 0, 0]
    # env 0: episode started at frame 5 -> [0, 0, 5]; env 1: started at frame 3 -> [3, 4, 5].
    np.testing.assert_array_equal(b, [[0, 0, 5], [3, 4, 5]])
    jitted = jax.jit(push, compiler_options=CHEAP)(buf, frames[0], jnp.zeros(2, bool))
    np.testing.assert_array_equal(np.asarray(jitted)[..., 0, 0, 0], [[0, 5, 1], [4, 5, 1]])


def test_ring_buffer_across_auto_resets(episodes, replay):
    """Collected windows (built with push) equal windows rebuilt by hand from the replay:
    oldest -> newest, zeros before the episode's first observation, never two episodes."""
    ds = episodes[1]
    img, start = replay["image"], replay["start"]
    n = ds.window
    assert replay["start"][1:].any(), "the rollout should cross an auto-reset"
    for row in range(len(ds)):
        p, e = int(ds.extras["position"][row]), int(ds.extras["env_index"][row])
        first = max(i for i in range(p + 1) if start[i, e])  # this episode's first position
        want = np.zeros((n, 5, 5, 3), np.uint8)
        for slot, i in enumerate(range(p - n + 1, p + 1)):
            if i >= first:
                want[slot] = img[i, e]
        np.testing.assert_array_equal(ds.windows[row], want)
        assert ds.extras["step"][row] == p - first


# -------------------------------------------------------------------- violation probability


def test_violation_prob_table_path_matches_direct():
    # Initialised under jit: eager Flax initialisation compiles op by op.
    new_checker = jax.jit(checker.model.new_checker, static_argnums=0, compiler_options=CHEAP)
    tc = new_checker(TINY, jax.random.PRNGKey(2))
    table = sentence_table()
    n = table.shape[0] + 30  # larger than the table: the lookup path
    rng = np.random.default_rng(0)
    toks = jnp.asarray(table[rng.integers(0, len(table), n)])
    buf = jnp.asarray(rng.integers(0, 6, (n, TINY.window, 5, 5, 3)), jnp.uint8)
    direct = jax.nn.sigmoid(jax.jit(TrainedChecker.logits, compiler_options=CHEAP)(tc, buf, toks))
    p = jax.jit(violation_prob, compiler_options=CHEAP)(tc, buf, toks)
    assert p.shape == (n,) and p.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(p), np.asarray(direct), rtol=1e-5, atol=1e-6)
    # A row that is no sentence of the grammar gets NaN, loudly; the others are unaffected.
    odd = toks.at[0].set(jnp.arange(1, language.MAX_LEN + 1) % language.vocab_size())
    codes = np.asarray(jax.jit(sentence_codes, compiler_options=CHEAP)(tc, odd))
    assert np.isnan(codes[0]).all() and np.isfinite(codes[1:]).all()
