"""agents.baseline, the PureJaxRL-style learner, at a tiny size (8 envs x 16 steps x 2 updates).

The harness runs on a small chain env everywhere; on NAVIX DoorKey-8x8 (its default env) when
navix is installed: one compile (~10-15 s on 2 shared cores, NAVIX's step dominates it).
"""

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents import baseline

N, T, U, EPOCHS, MB = 8, 16, 2, 2, 4


class Chain:
    """Gymnax-style 5-cell corridor: action 1 steps right, 0 left; reward 1 at the end cell,
    where the episode ends and restarts at cell 0. One-hot uint8 observation."""

    def reset(self, key, params=None):
        pos = jnp.int32(0)
        return jax.nn.one_hot(pos, 5, dtype=jnp.uint8), pos

    def step(self, key, state, action, params=None):
        pos = jnp.clip(state + 2 * action - 1, 0, 4)
        done = pos == 4
        pos_next = jnp.where(done, 0, pos)
        obs = jax.nn.one_hot(pos_next, 5, dtype=jnp.uint8)
        return obs, pos_next, done.astype(jnp.float32), done, {}

    def observation_shape(self, params=None):
        return (5,)

    def num_actions(self, params=None):
        return 2


def test_harness_on_an_injected_env_learns_the_chain():
    env = baseline.LogWrapper(baseline.FlattenObservation(Chain()))
    res = baseline.measure(total_timesteps=N * T * 30, num_envs=N, num_steps=T,
                           update_epochs=EPOCHS, num_minibatches=MB, env=env,
                           return_output=True)  # fmt: skip
    assert res["total_timesteps"] == N * T * 30 and res["sps"] > 0 and res["compile_s"] > 0
    lengths = np.asarray(res["output"]["metrics"]["returned_episode_lengths"])
    done = np.asarray(res["output"]["metrics"]["returned_episode"])
    first, last = lengths[:5][done[:5]].mean(), lengths[-5:][done[-5:]].mean()
    assert last < first and last < 6  # the shortest episode is 4 steps


@pytest.fixture(scope="module")
def result():
    pytest.importorskip("navix")
    return baseline.measure(
        total_timesteps=N * T * U + 5,  # rounded down to whole updates, as in PureJaxRL
        num_envs=N,
        num_steps=T,
        update_epochs=EPOCHS,
        num_minibatches=MB,
        seed=0,
        return_output=True,
    )


def test_measure_report(result):
    report = {k: v for k, v in result.items() if k != "output"}
    assert set(report) >= {"sps", "compile_s", "total_timesteps", "device"}
    assert math.isfinite(report["sps"]) and report["sps"] > 0
    assert math.isfinite(report["compile_s"]) and report["compile_s"] > 0
    assert report["total_timesteps"] == N * T * U
    assert isinstance(report["device"], str) and report["device"]
    json.dumps(report)


def test_train_output_shapes(result):
    out = result["output"]
    metrics = out["metrics"]
    assert set(metrics) == {
        "returned_episode",
        "returned_episode_returns",
        "returned_episode_lengths",
        "timestep",
    }
    for v in metrics.values():
        assert v.shape == (U, T, N)
    # LogWrapper's per-env step counter runs 1..U*T across updates.
    ts = np.asarray(metrics["timestep"])
    np.testing.assert_array_equal(ts[:, :, 0].reshape(-1), np.arange(1, U * T + 1))
    assert np.all(np.asarray(metrics["returned_episode_lengths"]) >= 0)

    total_loss, (value_loss, actor_loss, entropy) = out["loss_info"]
    for x in (total_loss, value_loss, actor_loss, entropy):
        assert x.shape == (U, EPOCHS, MB)
        assert np.all(np.isfinite(np.asarray(x)))
    # 7 NAVIX actions, near-uniform policy at init (actor head init scale 0.01).
    assert np.all(np.asarray(entropy) > 0.9 * np.log(7))

    train_state, env_state, last_obs, rng = out["runner_state"]
    assert last_obs.shape == (N, 8 * 8 * 3) and last_obs.dtype == np.uint8
    assert int(train_state.step) == U * EPOCHS * MB
    leaves = jax.tree_util.tree_leaves(train_state.params)
    assert all(np.all(np.isfinite(np.asarray(p))) for p in leaves)


def test_config_validation():
    assert baseline.resolve_config({"TOTAL_TIMESTEPS": 300, "NUM_ENVS": 8, "NUM_STEPS": 16})[
        "NUM_UPDATES"] == 2  # fmt: skip
    with pytest.raises(ValueError, match="at least one"):
        baseline.make_train({"TOTAL_TIMESTEPS": 10, "NUM_ENVS": 8, "NUM_STEPS": 16})
    with pytest.raises(ValueError, match="divisible"):
        baseline.make_train(
            {"TOTAL_TIMESTEPS": 1000, "NUM_ENVS": 3, "NUM_STEPS": 5, "NUM_MINIBATCHES": 2}
        )


def test_the_same_learner_runs_on_a_jaxgrid_id():
    res = baseline.measure(total_timesteps=N * T * U, num_envs=N, num_steps=T,
                           update_epochs=EPOCHS, num_minibatches=MB,
                           env_name="MiniGrid-Empty-5x5-v0", return_output=True)  # fmt: skip
    assert res["total_timesteps"] == N * T * U and res["sps"] > 0
    # The egocentric 7x7x3 view, flattened: 147 uint8 values per observation.
    env = baseline.make_env("MiniGrid-Empty-5x5-v0")
    obs, _ = env.reset(jax.random.PRNGKey(0))
    assert obs.shape == (147,) and obs.dtype == jnp.uint8
    assert env.observation_shape() == (147,) and env.num_actions() == 7
    done = np.asarray(res["output"]["metrics"]["returned_episode"])
    assert done.shape == (U, T, N)


def test_jaxgrid_ids_take_no_navix_options():
    with pytest.raises(ValueError, match="NAVIX ids only"):
        baseline.make_env("MiniGrid-Empty-5x5-v0", observation_fn=None)
