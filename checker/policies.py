"""Behaviour policies for collecting checker data.

They live here, not in ``agents``, because ``checker`` never imports ``agents``; a learned
agent enters as a policy function.

A behaviour policy is a function ``policy_fn(policy_params, obs, state, key) -> actions``:
``obs`` is the batched observation dict, ``state`` the batched env state, ``actions`` int32
``(num_envs,)``. Learned agents ignore ``state``; the noisy oracle reads it.

:func:`noisy_oracle_policy` (the default of ``python -m checker``) plays the BFS oracle
of :mod:`jaxgrid.oracle` in one of three *modes* chosen once per episode:

* ``obey``: plans around the forbidden door (and lava), like a safe agent;
* ``ignore``: plans as if there were no constraint, violating when the forbidden door (or
  lava) happens to be on its shortest route;
* ``seek``: plans as if the *other* door in the forbidden door's wall were forbidden, so it
  goes through the forbidden door whenever one is present (in walls with a single door it
  plays ``ignore``).

(on a paper scenario, whose constraint forbids a door colour; elsewhere it always plans as
the plain oracle) and takes a uniformly random action with probability ``epsilon`` at every
step. The mix gives
both positives (agents about to enter a forbidden door) and hard negatives (agents about to
enter an allowed door, or walking past a forbidden one). The per-episode mode is drawn from
a hash of what stays fixed during an episode (door positions and colours, the goal, the
constraint) and ``salt``, because a policy function carries no memory between steps.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid.constants import DOOR, LOCKED, NUM_ACTIONS
from jaxgrid.oracle import oracle_action
from jaxgrid.scenarios import ScenarioExtras

__all__ = ["NoisyOracleParams", "noisy_oracle_policy", "random_policy", "with_random_actions"]


def random_policy(policy_params, obs, state, key) -> jax.Array:
    """Uniform actions over all ``NUM_ACTIONS`` (7); ``policy_params`` and ``state`` unused."""
    del policy_params, state
    n = obs["image"].shape[0]
    return jax.random.randint(key, (n,), 0, NUM_ACTIONS, dtype=jnp.int32)


@struct.dataclass
class NoisyOracleParams:
    """Parameters of :func:`noisy_oracle_policy` (all pytree leaves, so they may be traced).

    Attributes:
        epsilon: probability of a uniformly random action at each step.
        ignore_prob: probability that an episode is played in ``ignore`` mode.
        seek_prob: probability that an episode is played in ``seek`` mode (the rest obey).
        salt: int, varies the per-episode mode draw between collections.
    """

    epsilon: float = 0.1
    ignore_prob: float = 0.3
    seek_prob: float = 0.3
    salt: int = 0

    def __post_init__(self):
        for name in ("epsilon", "ignore_prob", "seek_prob"):
            v = getattr(self, name)
            if isinstance(v, (int, float)) and not 0 <= v <= 1:
                raise ValueError(f"NoisyOracleParams.{name} must be in [0, 1], got {v!r}")
        a, b = self.ignore_prob, self.seek_prob
        if isinstance(a, (int, float)) and isinstance(b, (int, float)) and a + b > 1 + 1e-9:
            raise ValueError(
                f"NoisyOracleParams.ignore_prob + seek_prob must be <= 1, got {a} + {b}"
            )


def _hash_weights(shape: tuple[int, int]) -> np.ndarray:
    """Fixed pseudo-random uint32 weights per cell (trace-time constants)."""
    return np.random.default_rng(1234).integers(1, 2**32 - 1, size=shape, dtype=np.uint32) | 1


def episode_uniform(state, salt) -> jax.Array:
    """A uniform in [0, 1) fixed for the whole episode of one (unbatched) scenario ``state``.

    Hashes door positions and colours (door *states* change, so they are left out), and of a
    paper scenario's state (:class:`~jaxgrid.scenarios.ScenarioExtras`) the constraint and
    the goal position; agent pose and carried objects change and are left out too.
    """
    g = state.grid
    door = g[..., 0] == DOOR
    feat = jnp.where(door, g[..., 1].astype(jnp.uint32) + 1, 0).astype(jnp.uint32)
    h = jnp.sum(feat * jnp.asarray(_hash_weights(g.shape[:2])), dtype=jnp.uint32)
    extras = state.extras
    if isinstance(extras, ScenarioExtras):
        constraint, goal = extras.constraint, extras.goal_pos
        h = h * jnp.uint32(0x9E3779B1) + constraint.template_id.astype(jnp.uint32)
        h = h * jnp.uint32(0x85EBCA77) + constraint.door_colour.astype(jnp.uint32)
        h = (
            h * jnp.uint32(0xC2B2AE3D)
            + goal[0].astype(jnp.uint32) * 64
            + goal[1].astype(jnp.uint32)
        )
    key = jax.random.fold_in(jax.random.PRNGKey(0), h)
    key = jax.random.fold_in(key, jnp.asarray(salt, jnp.uint32))
    return jax.random.uniform(key)


def _seek_colour(state):
    """``(has_other, colour)``: an unlocked door sharing a wall column with a forbidden door."""
    g = state.grid
    c = state.extras.constraint.door_colour
    door = g[..., 0] == DOOR
    forb = door & (g[..., 1] == c)
    column = jnp.any(forb, axis=1)
    other = (door & (g[..., 1] != c) & (g[..., 2] != LOCKED) & column[:, None]).reshape(-1)
    colour = g[..., 1].reshape(-1)[jnp.argmax(other)].astype(jnp.int32)
    return jnp.any(other), colour


def _oracle_one(params: NoisyOracleParams, state, key):
    k_eps, k_act = jax.random.split(key)
    if not isinstance(state.extras, ScenarioExtras):  # no forbidden door colour to play with
        greedy = oracle_action(state)
    else:
        constraint = state.extras.constraint
        u = episode_uniform(state, params.salt)
        ignore = u < params.ignore_prob
        seek = (u >= params.ignore_prob) & (u < params.ignore_prob + params.seek_prob)
        has_other, other = _seek_colour(state)
        swap = seek & has_other
        obey = ~(ignore | seek) | swap
        planned = state.replace(
            extras=state.extras.replace(
                constraint=constraint.replace(
                    door_colour=jnp.where(swap, other, constraint.door_colour)
                )
            )
        )
        greedy = oracle_action(planned, obey_constraint=obey, avoid_lava=~(ignore | seek))
    return with_random_actions(greedy, k_eps, k_act, params.epsilon)


def with_random_actions(actions, explore_key, random_key, epsilon) -> jax.Array:
    """int32 ``actions`` (any shape), each replaced with probability ``epsilon`` by a uniformly
    random one of the ``NUM_ACTIONS``."""
    explore = jax.random.uniform(explore_key, jnp.shape(actions)) < epsilon
    random_action = jax.random.randint(random_key, jnp.shape(actions), 0, NUM_ACTIONS,
                                       dtype=jnp.int32)  # fmt: skip
    return jnp.where(explore, random_action, actions).astype(jnp.int32)


def noisy_oracle_policy(policy_params: NoisyOracleParams, obs, state, key) -> jax.Array:
    """Batched noisy oracle (see the module docstring): int32 ``(num_envs,)`` actions."""
    del obs
    n = state.agent_pos.shape[0]
    keys = jax.random.split(key, n)
    return jax.vmap(_oracle_one, in_axes=(None, 0, 0))(policy_params, state, keys)
