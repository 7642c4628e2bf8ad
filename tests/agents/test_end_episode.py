"""``PPOConfig.end_episode``: the learner ends a training episode where its shaping signal
fires, as a terminal step followed by a fresh episode."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from helpers.agents_cases import TINY, fast_jit

from agents.train import make_learner

# An untrained checker alarms on about half the steps at threshold 0.5; TwoRooms' own
# episodes last up to 100 steps, so within 16 steps almost only alarms end them.
ALARMING = dataclasses.replace(TINY, num_steps=16, total_timesteps=16 * 8 * 2,
                               reward_mode="checker", end_episode=True)  # fmt: skip


def _rollout(config, checker):
    learner = make_learner(config, checker)

    @fast_jit
    def go(key):
        runner = learner.init(key)
        env, traj, stats = learner.rollout(runner, key)
        return traj, stats, env.ep_length

    return jax.device_get(go(jax.random.PRNGKey(4)))


def test_every_alarm_ends_the_episode(tiny_checker):
    traj, stats, ep_length = _rollout(ALARMING, tiny_checker)
    alarms, episodes = int(stats["alarms"].sum()), int(stats["episodes"].sum())
    assert alarms > 10
    assert episodes >= alarms and int(traj.done.sum()) == episodes
    # A step that ended on an alarm is terminal: its reward is the env's minus the penalty
    # (no bootstrap from a later observation), and the env restarted there.
    assert np.all(traj.reward[traj.done] <= 0.0)
    assert np.all(ep_length <= 16)


@pytest.mark.slow
def test_without_it_alarms_only_cost_the_penalty(tiny_checker):
    traj, stats, _ = _rollout(dataclasses.replace(ALARMING, end_episode=False), tiny_checker)
    assert int(stats["alarms"].sum()) > 10 and int(stats["episodes"].sum()) == 0
