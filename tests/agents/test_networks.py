"""``agents.networks``: the matmul convolution equals flax's ``VALID`` convolution."""

from __future__ import annotations

import flax.linen as nn
import jax
import numpy as np
import pytest

from agents.networks import PatchConv


@pytest.mark.parametrize("shape", [(4, 5, 5, 8), (2, 7, 6, 3)])
def test_patch_conv_equals_flax_conv(shape):
    x = jax.random.normal(jax.random.PRNGKey(0), shape)
    params = PatchConv(16).init(jax.random.PRNGKey(1), x)
    ours = PatchConv(16).apply(params, x)
    ref = nn.Conv(16, (3, 3), padding="VALID").apply(params, x)
    np.testing.assert_allclose(ours, ref, rtol=1e-5, atol=1e-5)
