"""checker.model: the network's interface (shapes, jit, its decomposition into language,
state and classifier parts) and configuration errors."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.checker_cases import TINY
from helpers.xla import CHEAP

from checker import Checker, CheckerConfig
from checker.model import candidate_logits, init_params
from jaxgrid.sentences import PAPER

# ------------------------------------------------------------------------------------ model


def test_model_shapes_jit_and_decomposition():
    cfg = TINY
    init = jax.jit(init_params, static_argnums=0, compiler_options=CHEAP)  # eager: op by op
    params = init(cfg, jax.random.PRNGKey(0))
    m = Checker(cfg)
    b = 6
    w = jax.random.randint(jax.random.PRNGKey(1), (b, cfg.window, 5, 5, 3), 0, 6).astype(jnp.uint8)
    toks = jnp.asarray(PAPER.tokens()[:b])
    # Eager Flax RNNs compile op by op: jit instead.
    apply = jax.jit(m.apply, static_argnames="method", compiler_options=CHEAP)
    logits = apply(params, w, toks)
    assert logits.shape == (b,) and logits.dtype == jnp.float32
    lang = apply(params, toks, method=Checker.encode_language)
    states = apply(params, w, method=Checker.embed_states)
    assert lang.shape == (b, cfg.gru_dim) and states.shape == (b, cfg.window, cfg.state_dim)
    again = apply(params, states, lang, method=Checker.classify)
    np.testing.assert_allclose(np.asarray(logits), np.asarray(again), rtol=1e-5, atol=1e-6)
    # Padding is ignored: more trailing pads give the same sentence code.
    longer = jnp.concatenate([toks, jnp.zeros((b, 4), jnp.int32)], axis=1)
    np.testing.assert_allclose(
        np.asarray(apply(params, longer, method=Checker.encode_language)), np.asarray(lang),
        rtol=1e-5, atol=1e-6,
    )  # fmt: skip
    # Any leading shape for embed_states.
    assert apply(params, w[0, 0], method=Checker.embed_states).shape == (cfg.state_dim,)


@pytest.mark.parametrize(
    "window, kernel, layers",
    [(5, 3, 2), (1, 3, 1), (2, 3, 2), (4, 2, 1), (3, 5, 2), (6, 1, 1), (2, 4, 3), (5, 4, 2)],
)
def test_candidate_logits_equal_the_classifier_on_each_window(window, kernel, layers):
    """The shield's split computation (shared past once per env, each candidate's own
    share after) gives the classifier's logit of every (past + candidate) window: windows
    shorter than, as long as and longer than the temporal kernel, odd and even kernels."""
    cfg = CheckerConfig(
        window=window, temporal_kernel=kernel, mlp_layers=layers, gru_dim=16, state_dim=8,
        temporal_channels=6, mlp_dim=12,
    )  # fmt: skip
    params = jax.jit(init_params, static_argnums=0, compiler_options=CHEAP)(
        cfg, jax.random.key(window * 10 + kernel)
    )
    # Nonzero biases, so that a bias counted once too often (or not at all) shows.
    params = jax.tree.map(lambda x: x + 0.3 * jax.random.normal(jax.random.key(3), x.shape),
                          params)  # fmt: skip
    e, a = 4, 7
    k_past, k_cand, k_lang = jax.random.split(jax.random.key(1), 3)
    past = jax.random.normal(k_past, (e, window - 1, cfg.state_dim))
    cand = jax.random.normal(k_cand, (e, a, cfg.state_dim))
    lang = jax.random.normal(k_lang, (e, cfg.gru_dim))
    got = jax.jit(candidate_logits, static_argnums=1, compiler_options=CHEAP)(
        params, cfg, past, cand, lang
    )
    windows = jnp.concatenate(
        [jnp.broadcast_to(past[:, None], (e, a) + past.shape[1:]), cand[:, :, None]], axis=2
    ).reshape((e * a, window, cfg.state_dim))
    classify = jax.jit(Checker(cfg).apply, static_argnames="method", compiler_options=CHEAP)
    want = classify(params, windows, jnp.repeat(lang, a, axis=0), method=Checker.classify)
    assert got.shape == (e, a)
    np.testing.assert_allclose(np.asarray(got), np.asarray(want).reshape(e, a),
                               rtol=1e-5, atol=1e-5)  # fmt: skip


def test_config_rejects_bad_fields():
    with pytest.raises(ValueError, match="gru_dim"):
        CheckerConfig(gru_dim=0)
    with pytest.raises(ValueError, match="view_size"):
        CheckerConfig(view_size=4)
