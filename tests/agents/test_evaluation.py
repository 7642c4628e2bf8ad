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
from jaxgrid.types import TimeStep


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
    ep = jax.device_get(
        fast_jit(lambda k: play_episodes(lava, random_act, k, 16, track=track))(
            jax.random.PRNGKey(3)
        )
    )
    assert ep["tracked"].shape == (16, 2)
    np.testing.assert_array_equal(ep["tracked"][:, 0], ep["length"] >= 10)
    assert not ep["tracked"][:, 1].any()
    assert 0 < (ep["length"] >= 10).sum() < 16  # both kinds of episode occur
    untracked = fast_jit(lambda k: play_episodes(lava, random_act, k, 16))(jax.random.PRNGKey(3))
    assert "tracked" not in untracked


# ------------------------------------------------------------------------------ cost metrics
# A scripted env: each episode plays one row of COSTS (its info["cost"] step by step) and ends
# after LENGTHS[row] steps; the env keeps stepping (and costing) after that, as raw envs do.
COSTS = np.array(
    [
        [0, 1, 1, 0, 1, 1, 1, 0],  # cost 5, longest run 3 (the second)
        [1, 1, 1, 1, 0, 0, 0, 0],  # cost 4, run 4 from the first step
        [0, 0, 0, 0, 0, 0, 0, 0],  # no cost
        [1, 1, 0, 1, 1, 1, 1, 1],  # ends after 3 steps: cost 2, run 2 (the rest never counts)
        [0, 0, 0, 0, 0, 1, 1, 1],  # a run of 3 up to the last step
    ],
    np.float32,
)
LENGTHS = np.array([8, 8, 8, 3, 8])
EPISODE_COST = np.array([5.0, 4.0, 0.0, 2.0, 3.0])
LONGEST_RUN = np.array([3, 4, 0, 2, 3])


class ScriptedCosts:
    """Episodes whose costs are a row of :data:`COSTS`, drawn by the reset key."""

    max_steps = COSTS.shape[1]

    def _ts(self, state, cost):
        row, t = state
        done = t >= jnp.asarray(LENGTHS)[row]
        obs = {"direction": jnp.zeros((), jnp.int32), "row": row}
        return TimeStep(observation=obs, reward=jnp.zeros((), jnp.float32), terminated=done,
                        truncated=jnp.zeros((), bool), discount=jnp.ones((), jnp.float32),
                        info={"cost": cost, "violation": cost > 0})  # fmt: skip

    def reset(self, key):
        state = (jax.random.randint(key, (), 0, len(COSTS)), jnp.zeros((), jnp.int32))
        return state, self._ts(state, jnp.zeros((), jnp.float32))

    def step(self, state, action):
        row, t = state
        cost = jnp.asarray(COSTS)[row, jnp.minimum(t, self.max_steps - 1)]
        state = (row, t + 1)
        return state, self._ts(state, cost)


def test_episode_cost_and_longest_costly_run_of_scripted_episodes():
    env = ScriptedCosts()
    idle = lambda obs, key: jnp.zeros(obs["direction"].shape, jnp.int32)  # noqa: E731
    # Which script each episode plays, read back through ``track``.
    track = lambda states: states[0][:, None] == jnp.arange(len(COSTS))  # noqa: E731
    play = fast_jit(lambda k: play_episodes(env, idle, k, 24, track=track))
    ep = jax.device_get(play(jax.random.PRNGKey(0)))
    rows = ep["tracked"].argmax(axis=1)
    assert (ep["tracked"].sum(axis=1) == 1).all() and len(set(rows)) == len(COSTS)
    np.testing.assert_array_equal(ep["length"], LENGTHS[rows])
    np.testing.assert_array_equal(ep["cost"], EPISODE_COST[rows])
    np.testing.assert_array_equal(ep["costly_run"], LONGEST_RUN[rows])
    assert ep["cost"].dtype == np.float32 and ep["costly_run"].dtype == np.int32
    rates = jax.device_get(summarise(ep))
    np.testing.assert_allclose(rates["mean_cost"], EPISODE_COST[rows].mean(), rtol=1e-6)
    np.testing.assert_allclose(rates["mean_costly_run"], LONGEST_RUN[rows].mean(), rtol=1e-6)
    assert rates["max_costly_run"] == 4.0


class CostLog:
    """An env that also logs in its state which steps of the episode cost (bool (T,))."""

    def __init__(self, env):
        self.env, self.max_steps = env, env.max_steps

    def reset(self, key):
        state, ts = self.env.reset(key)
        return (state, jnp.zeros((), jnp.int32), jnp.zeros((self.max_steps,), bool)), ts

    def step(self, state, action):
        state, t, log = state
        state, ts = self.env.step(state, action)
        log = log.at[jnp.minimum(t, self.max_steps - 1)].set(ts.info["cost"] > 0)
        return (state, t + 1, log), ts


def test_cost_metrics_match_the_costly_steps_of_hazard_rooms_episodes():
    """Lava costs without ending the episode: walks along its strips make runs of costs."""
    env = CostLog(jaxgrid.make("HazardRooms-v0", sentences=("avoid lava",), max_steps=60))

    def mostly_forward(obs, key):
        k1, k2 = jax.random.split(key)
        shape = obs["direction"].shape
        turn = jax.random.randint(k2, shape, 0, 2)  # left or right
        return jnp.where(jax.random.uniform(k1, shape) < 0.7, 2, turn)

    play = fast_jit(lambda k: play_episodes(env, mostly_forward, k, 64, track=lambda s: s[2]))
    ep = jax.device_get(play(jax.random.PRNGKey(1)))
    costly = ep["tracked"]  # (E, T): which steps of each episode cost (none after its end)

    def longest(flags):
        best = run = 0
        for f in flags:
            run = run + 1 if f else 0
            best = max(best, run)
        return best

    np.testing.assert_array_equal(ep["cost"], costly.sum(axis=1))
    np.testing.assert_array_equal(ep["costly_run"], [longest(f) for f in costly])
    assert ep["costly_run"].max() >= 2  # the case an average cost hides does occur


def test_a_budget_is_spent_as_the_limits_share_of_each_cost():
    """Each cost spends ``cost / limit`` of the budget, which stays in [-1, 1]; a limit of 0
    is spent by any cost."""
    budget = np.array([1.0, 0.5, 0.5, -0.9, 1.0], np.float32)
    cost = np.array([0.0, 1.0, 0.25, 1.0, 1.0], np.float32)
    np.testing.assert_allclose(spend(budget, cost, 2.0), [1.0, 0.0, 0.375, -1.0, 0.5])
    np.testing.assert_array_equal(spend(budget, cost, 0.0), [1.0, -1.0, -1.0, -1.0, -1.0])
