"""``agents.networks``: the matmul convolutions equal flax's ``VALID`` convolution, the split
memory flax's ``GRUCell``."""

from __future__ import annotations

import flax.linen as nn
import jax
import numpy as np
import pytest

from agents.networks import PatchConv


@pytest.mark.parametrize("form", ["auto", "dense", "rows"])
@pytest.mark.parametrize("shape", [(4, 5, 5, 8), (2, 7, 6, 3), (3, 7, 7, 8)])
def test_patch_conv_equals_flax_conv(shape, form):
    x = jax.random.normal(jax.random.PRNGKey(0), shape)
    params = PatchConv(16).init(jax.random.PRNGKey(1), x)
    ours = PatchConv(16, form=form).apply(params, x)
    ref = nn.Conv(16, (3, 3), padding="VALID").apply(params, x)
    np.testing.assert_allclose(ours, ref, rtol=1e-5, atol=1e-5)
    grad = lambda f: jax.grad(lambda p: (f(p) ** 2).sum())(params)  # noqa: E731
    ours_grad = grad(lambda p: PatchConv(16, form=form).apply(p, x))
    ref_grad = grad(lambda p: nn.Conv(16, (3, 3), padding="VALID").apply(p, x))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-4),
                 ours_grad, ref_grad)  # fmt: skip


def test_patch_conv_refuses_an_unknown_form():
    x = np.zeros((1, 5, 5, 2), np.float32)
    with pytest.raises(ValueError, match="'cols'"):
        PatchConv(4, form="cols").init(jax.random.PRNGKey(0), x)


def test_recurrent_heads_are_flax_gru_cell():
    """The memory's split form (input terms for a whole sequence, one recurrent matmul per
    step) computes flax's ``GRUCell`` with the same parameters, under its names."""
    from agents.networks import ActorCritic

    net = ActorCritic(recurrent=True)
    image, direction = np.zeros((3, 7, 7, 3), np.uint8), np.zeros((3,), np.int32)
    params = net.init(jax.random.key(0), image, direction, np.zeros((1, 13), np.int32),
                      method=ActorCritic.init_all)  # fmt: skip
    h, memory = jax.random.normal(jax.random.key(1), (2, 3, net.hidden))
    ours = net.apply(params, h, memory, method=ActorCritic.heads)
    gru = {"params": params["params"]["core"]}
    ref_memory = nn.GRUCell(net.hidden).apply(gru, memory, h)[0]
    np.testing.assert_allclose(ours[3], ref_memory, rtol=1e-5, atol=1e-6)
    ref_heads = net.apply(params, h, ref_memory, method=ActorCritic.read)
    for a, b in zip(ours[:3], ref_heads, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)


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


def test_memory_skip_lets_the_heads_read_the_view():
    """With ``memory_skip`` the heads read the observation features beside the memory: with
    the same memory, two views give different logits even where the GRU's output is the same
    (the memory carried through unchanged). Without it they cannot."""
    from agents.networks import ActorCritic

    image, direction = np.zeros((1, 7, 7, 3), np.uint8), np.zeros((1,), np.int32)
    tokens = np.zeros((1, 13), np.int32)
    for skip in (False, True):
        net = ActorCritic(recurrent=True, memory_skip=skip)
        params = net.init(jax.random.key(0), image, direction, tokens,
                          method=ActorCritic.init_all)  # fmt: skip
        width = net.hidden * (2 if skip else 1)
        assert params["params"]["mix"]["kernel"].shape == (width, net.hidden)
        memory = jax.random.normal(jax.random.key(1), (1, net.hidden))
        h1, h2 = jax.random.normal(jax.random.key(2), (2, 1, net.hidden))
        logits = [net.apply(params, h, memory, method=ActorCritic.read)[0] for h in (h1, h2)]
        assert (np.abs(logits[0] - logits[1]).max() > 1e-6) == skip


def test_memory_skip_needs_a_memory():
    from agents.config import PPOConfig

    with pytest.raises(ValueError, match="memory_skip needs recurrent=True"):
        PPOConfig(memory_skip=True)
    assert PPOConfig(recurrent=True, memory_skip=True).memory_skip
