"""The recurrent policy option: memory carried through episodes, recomputed in the update.

The update's forward pass replays each env's rollout sequence through the GRU from the memory
the rollout began with, resetting it where an episode began. Before any gradient step it must
therefore reproduce exactly the log-probabilities the rollout acted with (PPO's ratio 1), on a
rollout whose episodes end and restart inside it.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.agents_cases import TINY, fast_jit

from agents.networks import start_memory
from agents.train import make_learner, make_train

RECURRENT = dataclasses.replace(
    TINY,
    recurrent=True,
    num_steps=24,
    total_timesteps=8 * 24 * 4,
    env_kwargs=(("max_steps", 10),),
    reward_mode="shaped",
)


@pytest.fixture(scope="module")
def rollout():
    learner = make_learner(RECURRENT)

    @fast_jit
    def go(key):
        runner = learner.init(key)
        env, traj, _, batch = learner.collect(runner, key)
        return runner, env, traj, batch

    return learner, go(jax.random.PRNGKey(3))


def _log_probs(learner, params, batch):
    logits, _, _ = learner.forward(params, batch)
    flat = jnp.asarray(batch["action"]).reshape(-1)
    return jnp.take_along_axis(jax.nn.log_softmax(logits), flat[:, None], axis=-1)[:, 0]


def test_the_update_replays_the_rollouts_log_probabilities(rollout):
    learner, (runner, _, traj, batch) = rollout
    assert np.asarray(traj.done).any(), "episodes must end inside the rollout"
    recomputed = fast_jit(lambda p, b: _log_probs(learner, p, b))(runner.params, batch)
    np.testing.assert_allclose(recomputed, np.asarray(traj.log_prob).reshape(-1), atol=1e-5)
    # Without the resets at episode starts the replay differs: the memory matters.
    no_reset = dict(batch, start=jnp.zeros_like(batch["start"]))
    wrong = fast_jit(lambda p, b: _log_probs(learner, p, b))(runner.params, no_reset)
    assert np.abs(np.asarray(wrong) - np.asarray(recomputed)).max() > 1e-4


def test_minibatches_are_whole_env_sequences(rollout):
    learner, (_, _, _, batch) = rollout
    mbs = learner.minibatches(batch, jax.random.PRNGKey(0))
    c = RECURRENT
    envs = c.num_envs // c.num_minibatches
    assert mbs["image"].shape[:3] == (c.num_minibatches, c.num_steps, envs)
    assert mbs["memory0"].shape[:2] == (c.num_minibatches, envs)
    # Every env's sequence lands, intact, in exactly one minibatch.
    actions = np.asarray(batch["action"]).T  # (E, T)
    got = np.asarray(mbs["action"]).transpose(0, 2, 1).reshape(-1, c.num_steps)
    assert sorted(map(tuple, got)) == sorted(map(tuple, actions))


def test_memory_restarts_with_each_episode(rollout):
    learner, (_, env, traj, _) = rollout
    assert env.memory.shape == (RECURRENT.num_envs, learner.network.memory_dim)
    ended = np.asarray(traj.done[-1])
    np.testing.assert_array_equal(np.asarray(env.memory)[ended], 0.0)
    assert np.abs(np.asarray(env.memory)[~ended]).max() > 0


@pytest.mark.slow
def test_recurrent_training_and_evaluation_run():
    out = jax.jit(make_train(RECURRENT))(jax.random.PRNGKey(0))
    assert np.isfinite(np.asarray(out["train"]["loss"])).all()
    assert out["eval"]["success_rate"].shape == (RECURRENT.num_chunks,)


def test_acting_needs_memory_only_when_recurrent():
    recurrent, memoryless = make_learner(RECURRENT), make_learner(TINY)
    runner = fast_jit(memoryless.init)(jax.random.PRNGKey(0))  # jitted: eager init is slower
    obs, key = runner.env.obs, jax.random.PRNGKey(1)
    actions = fast_jit(memoryless.act)(runner.params, obs, key)
    assert actions.shape == (TINY.num_envs,)
    params = fast_jit(recurrent.init)(jax.random.PRNGKey(0)).params
    with pytest.raises(ValueError, match="memory"):
        fast_jit(recurrent.act)(params, obs, key)
    memory = start_memory(recurrent.network, TINY.num_envs)
    actions, memory = fast_jit(recurrent.act)(params, obs, key, memory=memory)
    assert memory.shape == (TINY.num_envs, recurrent.network.memory_dim)
