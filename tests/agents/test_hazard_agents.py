"""PPO on HazardRooms: its own vocabulary, and only with a fixed list of sentences."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from helpers.agents_cases import TINY, fast_jit

from agents.train import make_learner
from jaxgrid.sentences import HAZARD_ROOMS

SENTENCES = (
    "avoid lava",
    "do not step on water more than twice",
    "after you pick up the key, do not use the red door and never stand next to lava",
)
CONFIG = dataclasses.replace(
    TINY, env_id="HazardRooms-v0", env_kwargs=(("sentences", SENTENCES),), reward_mode="shaped"
)


def test_drawn_conjunctions_are_refused_by_name():
    with pytest.raises(ValueError, match="sentences"):
        make_learner(dataclasses.replace(TINY, env_id="HazardRooms-v0"))


def test_the_policy_reads_the_rich_vocabulary():
    learner = make_learner(CONFIG)
    assert learner.network.vocab_size == HAZARD_ROOMS.vocab_size
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))
    env, traj, stats = fast_jit(lambda r: learner.rollout(r, r.key))(runner)
    # Every episode's sentence is a row of the table (-1 would mean an unknown sentence).
    assert (np.asarray(traj.sentence) >= 0).all()
    assert np.asarray(learner.table).shape[0] == len(SENTENCES)
    assert int(stats["episodes"].sum()) >= 0
