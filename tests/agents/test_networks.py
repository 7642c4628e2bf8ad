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


def test_film_codes_weigh_each_code_and_change_nothing_when_off():
    """With ``film_codes`` the sentence's weight of a code scales that code's one-hot slot:
    weight 0 (a scale of -1) for both the red and the blue slots makes a red cell and a blue
    one the same to the network, and any other weight tells them apart. Off, the sentence
    input keeps its width and the parameters their shapes."""
    from agents.networks import _SIZES, ActorCritic
    from jaxgrid.constants import COLOR_NAMES, OBJECT_NAMES

    image = np.zeros((1, 5, 5, 3), np.uint8)
    image[0, 2, 2] = (OBJECT_NAMES.index("door"), COLOR_NAMES.index("red"), 0)
    blue = image.copy()
    blue[0, 2, 2, 1] = COLOR_NAMES.index("blue")
    images, direction = np.concatenate([image, blue]), np.zeros((2,), np.int32)
    tokens = np.zeros((1, 13), np.int32)
    off, on = ActorCritic(), ActorCritic(film_codes=True)
    assert on.lang_dim == off.lang_dim + sum(_SIZES)
    init = lambda net: net.init(jax.random.key(0), images[:1], direction[:1], tokens,  # noqa: E731
                                method=ActorCritic.init_all)  # fmt: skip
    shapes = lambda p: jax.tree.map(np.shape, p)  # noqa: E731
    p_off, p_on = init(off), init(on)
    assert jax.tree.structure(p_off) == jax.tree.structure(p_on)
    assert shapes(p_off)["params"]["cells"] == shapes(p_on)["params"]["cells"]

    def values(weights):
        lang = np.full((2, on.lang_dim), 0.1, np.float32)
        lang[:, off.lang_dim :] = weights
        return np.asarray(on.apply(p_on, images, direction, lang)[1])

    slot = {c: len(OBJECT_NAMES) + COLOR_NAMES.index(c) for c in ("red", "blue")}
    muted = np.zeros(sum(_SIZES), np.float32)
    muted[[slot["red"], slot["blue"]]] = -1.0
    v = values(muted)
    assert v[0] == v[1]
    v = values(np.zeros(sum(_SIZES), np.float32))
    assert abs(v[0] - v[1]) > 1e-6
