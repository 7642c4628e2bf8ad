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
from checker.model import init_params
from jaxgrid.language import sentence_table

# ------------------------------------------------------------------------------------ model


def test_model_shapes_jit_and_decomposition():
    cfg = TINY
    init = jax.jit(init_params, static_argnums=0, compiler_options=CHEAP)  # eager: op by op
    params = init(cfg, jax.random.PRNGKey(0))
    m = Checker(cfg)
    b = 6
    w = jax.random.randint(jax.random.PRNGKey(1), (b, cfg.window, 5, 5, 3), 0, 6).astype(jnp.uint8)
    toks = jnp.asarray(sentence_table()[:b])
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


def test_config_rejects_bad_fields():
    with pytest.raises(ValueError, match="gru_dim"):
        CheckerConfig(gru_dim=0)
    with pytest.raises(ValueError, match="view_size"):
        CheckerConfig(view_size=4)
