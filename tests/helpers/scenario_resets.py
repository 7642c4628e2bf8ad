"""The batch of scenario resets the scenario and oracle tests share: ``N`` episodes per
scenario, from keys split off one seed, computed once per test process."""

from __future__ import annotations

import functools

import jax
import numpy as np

import jaxgrid
from helpers.xla import CHEAP

SCENARIOS = ("TwoRooms-v0", "TwoRoomsLava-v0", "ThreeRoomsKey-v0")
# Episodes per scenario, for the layout checks and the oracle alike: the batch of resets is the
# one the oracle plays (same keys).
N = 10_000
SEED = 42

# ``env`` is passed as a pytree (static config + the absent_colour_prob leaf), so each
# scenario and split compiles once whatever absent_colour_prob is.
_batch_reset = jax.jit(lambda env, keys: jax.vmap(env.reset)(keys), compiler_options=CHEAP)


@functools.cache
def resets(name: str, **overrides):
    """``(states, timesteps)`` of ``N`` resets (keys split from ``SEED``) as numpy arrays."""
    env = jaxgrid.make(name, **overrides)
    out = _batch_reset(env, jax.random.split(jax.random.PRNGKey(SEED), N))
    return jax.tree.map(np.asarray, out)
