"""Session fixtures of the checker's tests (built by ``helpers.checker_cases``): each test
process collects the TwoRooms rollout and the HazardRooms streams and trains the toy checker
at most once."""

from __future__ import annotations

import pytest
from helpers import checker_cases as cases

import jaxgrid


@pytest.fixture(scope="session")
def env():
    return jaxgrid.make("TwoRooms-v0")


@pytest.fixture(scope="session")
def episodes(env):
    """Full-episode datasets for lookahead 0, 1 and 2 of one deterministic rollout."""
    return cases.collect_episodes(env)


@pytest.fixture(scope="session")
def replay(env):
    """The rollout of ``episodes``, replayed step by step with an independent monitor."""
    return cases.replay_episodes(env)


@pytest.fixture(scope="session")
def toy():
    """``(train, test)`` of the synthetic door-colour set."""
    return cases.toy_split()


@pytest.fixture(scope="session")
def trained_toy(toy):
    """``(TrainedChecker, history)`` trained on ``toy``'s training split."""
    return cases.train_toy(toy[0])


@pytest.fixture(scope="session")
def streams():
    """16 HazardRooms streams of 60 frames (the memory checker's data)."""
    return cases.hazard_streams()
