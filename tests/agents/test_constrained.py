"""The constrained-RL baselines in the learner: each trains through the one rollout, loss and
update, and shows the behaviour that defines it on a tiny run: the PID Lagrangian's
multiplier follows its controller."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from helpers.agents_cases import TINY, fast_jit

from agents.train import make_train

# Threshold ~0: every step alarms, so the cost per episode is the rollout's steps over the
# episodes it finished, far above the limit; episodes of 5 steps end 8 or 16 times in the 8
# steps of an update, so the cost changes from one update to the next.
PID = dataclasses.replace(
    TINY, reward_mode="pid_lagrangian", checker_threshold=1e-6, cost_limit=0.25, pid_kp=0.5,
    pid_ki=0.1, pid_kd=0.2, env_kwargs=(("max_steps", 5),),
)  # fmt: skip


@pytest.fixture(scope="module")
def pid_run(tiny_checker):
    return jax.device_get(fast_jit(make_train(PID, tiny_checker))(jax.random.PRNGKey(0)))


def test_pid_lagrangian_multiplier_follows_its_controller(pid_run):
    """The multiplier of every update is the PID controller's on that update's cost per
    episode (no derivative at the first), and the runner keeps the controller's memory."""
    t = pid_run["train"]
    cost, lam = t["episode_cost"].ravel(), t["lagrange"].ravel()
    np.testing.assert_allclose(t["cost_rate"], 1.0)
    assert len(set(cost.tolist())) > 1  # the cost changes, so the derivative term acts
    integral, previous, expected = 0.0, cost[0], []
    for c in cost:
        error = c - PID.cost_limit
        integral = max(0.0, integral + error)
        rise = max(0.0, c - previous)
        expected.append(max(0.0, PID.pid_kp * error + PID.pid_ki * integral + PID.pid_kd * rise))
        previous = c
    np.testing.assert_allclose(lam, expected, rtol=1e-5)
    runner = pid_run["runner"]
    np.testing.assert_allclose(runner.pid.integral, integral, rtol=1e-5)
    assert runner.pid.cost == cost[-1] and runner.lagrange == lam[-1]
