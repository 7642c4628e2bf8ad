"""Smoke test of the PureJaxRL-style PPO baseline at a tiny size (8 envs x 16 steps x 2 updates).

One compile (~10-15 s on 2 shared cores: NAVIX's step dominates it), one run.
"""

import json
import math

import jax
import numpy as np
import pytest

pytest.importorskip("navix")

from benchmarks import purejaxrl_ppo as bench  # noqa: E402

N, T, U, EPOCHS, MB = 8, 16, 2, 2, 4


@pytest.fixture(scope="module")
def result():
    return bench.measure(
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
    with pytest.raises(ValueError, match="at least one"):
        bench.make_train({"TOTAL_TIMESTEPS": 10, "NUM_ENVS": 8, "NUM_STEPS": 16})
    with pytest.raises(ValueError, match="divisible"):
        bench.make_train(
            {"TOTAL_TIMESTEPS": 1000, "NUM_ENVS": 3, "NUM_STEPS": 5, "NUM_MINIBATCHES": 2}
        )
