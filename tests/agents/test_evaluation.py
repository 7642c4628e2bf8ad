"""``agents.evaluation``: fixed keys give fixed episodes; the oracle succeeds without
violations and earns MiniGrid's reward once per episode; the ``done`` action never
succeeds; a Saute budget is spent as the limit's share of each cost."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.agents_cases import fast_jit

import jaxgrid
from agents.evaluation import play_episodes, spend, summarise
from jaxgrid.oracle import oracle_action


@pytest.fixture(scope="module")
def two_rooms():
    return jaxgrid.make("TwoRooms-v0")


class StateInObs:
    """An env whose observation also carries the state, for privileged policies."""

    def __init__(self, env):
        self.env, self.max_steps = env, env.max_steps

    def reset(self, key):
        state, ts = self.env.reset(key)
        return state, ts.replace(observation={**ts.observation, "state": state})

    def step(self, state, action):
        state, ts = self.env.step(state, action)
        return state, ts.replace(observation={**ts.observation, "state": state})


ORACLE, NOISY_ORACLE, DONE = 0, 1, 2


@pytest.fixture(scope="module")
def play(two_rooms):
    """``play(key, policy)``: 8 TwoRooms episodes; one program for the three policies."""
    env = StateInObs(two_rooms)

    def act(policy, obs, key):
        oracle = jax.vmap(oracle_action)(obs["state"])
        k1, k2 = jax.random.split(key)
        shape = oracle.shape
        noisy = jnp.where(
            jax.random.uniform(k1, shape) < 0.3, jax.random.randint(k2, shape, 0, 3), oracle
        )
        done = jnp.full(shape, 6, jnp.int32)
        return jnp.select([policy == ORACLE, policy == NOISY_ORACLE], [oracle, noisy], done)

    @fast_jit
    def go(key, policy):
        return play_episodes(env, functools.partial(act, policy), key, 8)

    return lambda key, policy: jax.device_get(go(jax.random.PRNGKey(key), policy))


def test_play_episodes_is_deterministic_for_a_key(play):
    a, b, c = play(5, NOISY_ORACLE), play(5, NOISY_ORACLE), play(6, NOISY_ORACLE)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert not np.array_equal(a["length"], c["length"])
    assert np.all(a["violated"] == (a["violations"] > 0))
    assert np.all((a["length"] >= 1) & (a["length"] <= 100))


def test_oracle_succeeds_without_violations(play, two_rooms):
    ep = play(11, ORACLE)
    rates = jax.device_get(summarise(ep))
    assert rates["success_rate"] == 1.0 and rates["violation_rate"] == 0.0
    assert np.all(ep["violations"] == 0)
    # MiniGrid's reward, counted once per episode and only until the episode ends.
    np.testing.assert_allclose(
        ep["reward"], 1 - 0.9 * ep["length"] / two_rooms.max_steps, rtol=1e-6
    )


def test_done_action_never_succeeds(play, two_rooms):
    ep = play(2, DONE)
    assert not ep["success"].any() and not ep["violated"].any()
    np.testing.assert_array_equal(ep["length"], two_rooms.max_steps)
    np.testing.assert_array_equal(ep["reward"], 0.0)


def test_tracked_flags_hold_if_they_held_after_any_step_of_the_episode():
    lava = jaxgrid.make("TwoRoomsLava-v0")  # random walks end early in lava, or run on

    def random_act(obs, key):
        return jax.random.randint(key, obs["direction"].shape, 0, 3)

    # step_count >= 10 holds after some live step exactly when the episode lasted 10 steps
    track = lambda states: jnp.stack([states.step_count >= 10, states.step_count < 0], -1)  # noqa: E731
    ep = jax.device_get(fast_jit(lambda k: play_episodes(lava, random_act, k, 16,
                                                         track=track))(jax.random.PRNGKey(3)))
    assert ep["tracked"].shape == (16, 2)
    np.testing.assert_array_equal(ep["tracked"][:, 0], ep["length"] >= 10)
    assert not ep["tracked"][:, 1].any()
    assert 0 < (ep["length"] >= 10).sum() < 16  # both kinds of episode occur
    untracked = fast_jit(lambda k: play_episodes(lava, random_act, k, 16))(
        jax.random.PRNGKey(3))
    assert "tracked" not in untracked


def test_a_budget_is_spent_as_the_limits_share_of_each_cost():
    """Each cost spends ``cost / limit`` of the budget, which stays in [-1, 1]; a limit of 0
    is spent by any cost."""
    budget = np.array([1.0, 0.5, 0.5, -0.9, 1.0], np.float32)
    cost = np.array([0.0, 1.0, 0.25, 1.0, 1.0], np.float32)
    np.testing.assert_allclose(spend(budget, cost, 2.0), [1.0, 0.0, 0.375, -1.0, 0.5])
    np.testing.assert_array_equal(spend(budget, cost, 0.0), [1.0, -1.0, -1.0, -1.0, -1.0])
