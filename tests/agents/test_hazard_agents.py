"""PPO on HazardRooms: its own vocabulary, only with a fixed list of sentences, and the
env's own cost in the training statistics."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from helpers.agents_cases import TINY, fast_jit
from jax import lax

from agents.train import make_learner
from jaxgrid.sentences import HAZARD_ROOMS

SENTENCES = (
    "avoid lava",
    "do not step on water more than twice",
    "after you pick up the key, do not use the red door and never stand next to lava",
    "never stand next to lava",  # costly on many cells: random walks pay it
)
CONFIG = dataclasses.replace(
    TINY, env_id="HazardRooms-v0", env_kwargs=(("sentences", SENTENCES),), reward_mode="shaped"
)


def test_drawn_conjunctions_are_refused_by_name():
    with pytest.raises(ValueError, match="sentences"):
        make_learner(dataclasses.replace(TINY, env_id="HazardRooms-v0"))


@pytest.fixture(scope="module")
def rolled():
    learner = make_learner(CONFIG)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))
    env, traj, stats = fast_jit(lambda r: learner.rollout(r, r.key))(runner)
    return learner, runner, traj, stats


def test_the_policy_reads_the_rich_vocabulary(rolled):
    learner, _, traj, stats = rolled
    assert learner.network.vocab_size == HAZARD_ROOMS.vocab_size
    # Every episode's sentence is a row of the table (-1 would mean an unknown sentence).
    assert (np.asarray(traj.sentence) >= 0).all()
    assert np.asarray(learner.table).shape[0] == len(SENTENCES)
    assert int(stats["episodes"].sum()) >= 0


def test_the_rollout_counts_the_envs_own_cost(rolled):
    """``env_cost`` is the sum of ``info["cost"]`` of the rollout's steps (its actions
    replayed on the env batch), the monitor's cost whatever the mode's reward uses."""
    learner, runner, traj, stats = rolled

    @fast_jit
    def replay(states, actions):
        def step(states, action):
            states, ts = learner.envs.step(states, action)
            return states, (ts.info["cost"], ts.info["violation"])

        return lax.scan(step, states, actions)[1]

    cost, violation = jax.device_get(replay(runner.env.state, traj.action))
    np.testing.assert_array_equal(stats["env_cost"], cost.sum(axis=1))
    np.testing.assert_array_equal(stats["violations"], violation.sum(axis=1))
    # Budgets: costly steps that are not (yet) violations occur, and are counted.
    assert stats["env_cost"].sum() > stats["violations"].sum()
