"""The batch of scenario resets the scenario and oracle tests share: ``N`` episodes per
scenario, from keys split off one seed, computed once per test process."""

from __future__ import annotations

import functools

import jax
import numpy as np

import jaxgrid
from helpers.xla import batch_reset

SCENARIOS = ("TwoRooms-v0", "TwoRoomsLava-v0", "ThreeRoomsKey-v0")
# Episodes per scenario, for the layout checks and the oracle alike: the batch of resets is the
# one the oracle plays (same keys).
N = 10_000
SEED = 42


@functools.cache
def resets(name: str, **overrides):
    """``(states, timesteps)`` of ``N`` resets (keys split from ``SEED``) as numpy arrays."""
    env = jaxgrid.make(name, **overrides)
    out = batch_reset(env, jax.random.split(jax.random.PRNGKey(SEED), N))
    return jax.tree.map(np.asarray, out)
