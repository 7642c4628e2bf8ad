"""Session fixtures of the learner's tests: one small untrained checker for every file."""

from __future__ import annotations

import jax
import pytest
from helpers.agents_cases import CHECKER_CONFIG

from checker.model import new_checker


@pytest.fixture(scope="session")
def tiny_checker():
    return new_checker(CHECKER_CONFIG, jax.random.PRNGKey(7), env_id="TwoRooms-v0")
