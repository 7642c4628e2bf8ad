"""checker.memory_model: the memory checker's memory (zeroed exactly at episode starts; a
frame thirty steps back still counts, what a window of five cannot do), the actions it reads,
its memoryless ablation, its configuration's checks, its round trip through the store and its
stream interface (what PPO carries per env)."""

from __future__ import annotations

import dataclasses

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import checker_cases as cases

import checker
from checker import memory_model as MM
from checker.protocol import NO_ACTION
from jaxgrid.constants import FORWARD

SMALL = cases.MEMORY_SMALL


@pytest.fixture(scope="module")
def model_and_params():
    model = MM.MemoryChecker(SMALL)
    frames = cases.random_frames(jax.random.PRNGKey(0), 1, 4)
    starts = jnp.zeros((1, 4), bool)
    tokens = jnp.zeros((1, 4, SMALL.max_len), jnp.int32)
    return model, jax.jit(model.init)(jax.random.PRNGKey(1), frames, starts, tokens)


def test_memory_resets_at_starts_and_reaches_far_back(model_and_params):
    model, params = model_and_params
    t = 40
    a = cases.random_frames(jax.random.PRNGKey(2), 1, t)
    b = a.at[0, :10].set(cases.random_frames(jax.random.PRNGKey(3), 1, 10)[0])  # other first frames
    tokens = jnp.ones((1, t, SMALL.max_len), jnp.int32).at[..., 5:].set(0)
    apply = jax.jit(model.apply)
    starts = jnp.zeros((1, t), bool).at[0, 0].set(True)
    la, lb = apply(params, a, starts, tokens), apply(params, b, starts, tokens)
    assert np.abs(np.asarray(la - lb))[0, 35:].max() > 1e-6  # 25+ steps back still matters
    restart = starts.at[0, 10].set(True)  # a new episode at frame 10
    la, lb = apply(params, a, restart, tokens), apply(params, b, restart, tokens)
    np.testing.assert_array_equal(np.asarray(la)[0, 10:], np.asarray(lb)[0, 10:])
    assert np.abs(np.asarray(la - lb))[0, :10].max() > 1e-6


def test_a_checker_of_actions_reads_the_action_into_each_frame(tmp_path):
    trained = MM.new_memory_checker(dataclasses.replace(SMALL, actions=True), jax.random.PRNGKey(6))
    frames = cases.random_frames(jax.random.PRNGKey(7), 2, 6)
    starts = jnp.zeros((2, 6), bool).at[:, 0].set(True)
    tokens = jnp.ones((2, 6, SMALL.max_len), jnp.int32)
    a = jnp.full((2, 6), FORWARD, jnp.int32).at[:, 0].set(NO_ACTION)
    logits = jax.jit(trained.logits)
    la, lb = (
        np.asarray(logits(frames, starts, tokens, a)),
        logits(frames, starts, tokens, a.at[:, 3].set(0)),
    )
    np.testing.assert_array_equal(la[:, :3], np.asarray(lb)[:, :3])  # the past is unchanged
    assert np.abs(la[:, 3:] - np.asarray(lb)[:, 3:]).min() > 0  # that step and every later one
    with pytest.raises(ValueError, match="reads the action into each frame"):
        trained.logits(frames, starts, tokens)
    checker.save(trained, tmp_path / "m")
    assert checker.load(tmp_path / "m").config.actions


@pytest.mark.parametrize(
    "field, value",
    [("memory_dim", 0), ("view_size", 6), ("gru_dim", 2.5), ("mlp_dim", True), ("actions", 1)],
)
def test_bad_config_names_the_field(field, value):
    with pytest.raises(ValueError, match=f"MemoryCheckerConfig.{field}"):
        MM.MemoryCheckerConfig(**{field: value})


def test_memoryless_ablation_reads_each_frame_alone(model_and_params):
    model, params = model_and_params
    ablation = MM.MemoryChecker(dataclasses.replace(SMALL, memory=False))
    a = cases.random_frames(jax.random.PRNGKey(4), 1, 12)
    b = a.at[0, :6].set(cases.random_frames(jax.random.PRNGKey(5), 1, 6)[0])
    starts = jnp.zeros((1, 12), bool).at[0, 0].set(True)
    tokens = jnp.zeros((1, 12, SMALL.max_len), jnp.int32)
    la, lb = ablation.apply(params, a, starts, tokens), ablation.apply(params, b, starts, tokens)
    np.testing.assert_array_equal(np.asarray(la)[0, 6:], np.asarray(lb)[0, 6:])
    with pytest.raises(ValueError, match="MemoryCheckerConfig.memory must be a bool"):
        MM.MemoryCheckerConfig(memory=1)


def test_saved_memory_checker_loads_back_and_refuses_damage(tmp_path):
    trained = MM.new_memory_checker(
        SMALL, jax.random.PRNGKey(3), env_id="HazardRooms-v0", lookahead=0
    )
    checker.save(trained, tmp_path / "m")
    back = checker.load(tmp_path / "m")  # the one loader tells the two kinds apart
    assert isinstance(back, MM.TrainedMemoryChecker) and back.config == SMALL
    assert back.lookahead == 0 and back.shield_actions == (FORWARD,)
    chex.assert_trees_all_equal(back.params, trained.params)
    params = tmp_path / "m" / "params.msgpack"
    params.write_bytes(params.read_bytes()[:-7])
    with pytest.raises(ValueError, match="damaged parameter file"):
        checker.load(tmp_path / "m")


@pytest.mark.parametrize("actions", [False, True])
def test_stream_steps_equal_the_checker_over_the_whole_stream(actions):
    """``stream_start`` then ``stream_step`` frame by frame (what PPO carries per env) gives
    the logits of the stream read at once."""
    config = dataclasses.replace(SMALL, actions=actions)
    trained = MM.new_memory_checker(config, jax.random.PRNGKey(4))
    rng = np.random.default_rng(0)
    frames = jnp.asarray(rng.integers(0, 6, (3, 9, 7, 7, 3)), jnp.uint8)
    tokens = jnp.asarray(rng.integers(1, 20, (3, 9, SMALL.max_len)), jnp.int32)
    tokens = jnp.broadcast_to(tokens[:, :1], tokens.shape)  # one sentence per stream
    starts = jnp.zeros((3, 9), bool).at[:, 0].set(True)
    moves = jnp.asarray(rng.integers(0, NO_ACTION, (3, 9)), jnp.int32).at[:, 0].set(NO_ACTION)
    whole = jax.jit(trained.logits)(frames, starts, tokens, moves)  # jitted: eager is slower
    emb = jax.jit(trained.embed_states)(frames, moves)
    lang = jax.jit(trained.encode_language)(tokens)
    memory = jax.jit(trained.stream_start)(emb[:, 0], lang[:, 0])
    step = jax.jit(trained.stream_step)
    for t in range(1, 9):
        logit, memory = step(memory, emb[:, t], lang[:, t])
        np.testing.assert_allclose(logit, whole[:, t], atol=1e-5)
