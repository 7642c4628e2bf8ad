"""The jitted monitor against references, step by step, on random episodes.

HazardRooms episodes (every constraint type, drawn by the scenario) are played with biased
random actions; every step's ``cost`` and ``violation`` must equal those of
``helpers.monitor_reference``, which judges the sentence's parsed meaning with Python loops.
The default run checks about 3,000 steps per constraint type; ``-m slow`` 100,000. The
paper's scenarios, which the same monitor judges, are stepped against the paper's rule
stated directly (``paper_rule_step``): every observation, reward, termination, violation and
cost must be equal, on more than 10,000 steps per scenario.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.monitor_reference import ACTION_PROBS, compare, paper_rule_step

import jaxgrid
from jaxgrid import language as L
from jaxgrid import monitor as M
from jaxgrid.hazard import HazardRooms
from jaxgrid.oracle import oracle_action
from jaxgrid.wrappers import AutoReset


@pytest.mark.parametrize("steps_per_type", [3_000, pytest.param(100_000, marks=pytest.mark.slow)])
def test_monitor_matches_the_reference(steps_per_type):
    env = HazardRooms(width=13, height=13, max_steps=150)
    n = int(steps_per_type * len(L.CONSTRAINT_TYPES) / env.max_steps * 1.3)
    counted, steps = compare(env, 0, n)
    assert counted.min() >= steps_per_type, counted
    # The comparison saw every outcome: costs, violations, and costs without violations.
    active = steps["active"]
    assert steps["violation"][active].sum() > 100
    assert (steps["cost"][active] > 0).sum() > steps["violation"][active].sum()


def test_budget_counts_every_entry_and_flags_those_beyond_it():
    # A hand-made corridor: lava at x = 2, 4, 6; the agent walks right along y = 1.
    grid = np.zeros((9, 3, 3), np.uint8)
    grid[..., 0] = 1
    for x in (2, 4, 6):
        grid[x, 1] = (9, 0, 0)
    spec = M.encode(L.parse("do not step on lava more than twice"))
    mon = M.start(spec, jnp.asarray(grid))
    results = []
    for x in range(8):
        mon, cost, violation = M.update(
            mon, jnp.array([x, 1]), jnp.array([x + 1, 1]), jnp.array([1, 0, 0]),
            jnp.array([1, 0, 0]),
        )  # fmt: skip
        results.append((float(cost), bool(violation)))
    lava_steps = [(1.0, False), (1.0, False), (1.0, True)]
    assert [r for r in results if r[0]] == lava_steps
    assert int(mon.count[0]) == 3


def test_turning_in_a_zone_is_no_new_event():
    grid = np.zeros((5, 5, 3), np.uint8)
    grid[..., 0] = 1
    grid[2, 2] = (9, 0, 0)
    mon = M.start(M.encode(L.parse("never stand next to lava")), jnp.asarray(grid))
    stay = jnp.array([2, 1])
    empty = jnp.array([1, 0, 0])
    mon, cost, violation = M.update(mon, jnp.array([2, 0]), stay, empty, empty)
    assert (float(cost), bool(violation)) == (1.0, True)
    mon, cost, violation = M.update(mon, stay, stay, empty, empty)  # a turn
    assert (float(cost), bool(violation)) == (0.0, False)


def test_encode_rejects_three_clauses():
    c = L.parse("avoid lava").clauses[0]
    with pytest.raises(ValueError, match="1 to 2 clauses"):
        M.encode((c, c, c))


@functools.partial(jax.jit, static_argnames=("env", "n", "t"))
def _paper_steps(env, key, n, t):
    """``t`` auto-reset steps of ``n`` envs: a third of the actions random, the others the
    oracle's ignoring the constraint (through any door and lava), so forbidden cells are
    often entered. Per step and env: whether the env's step equals the reference's."""
    auto = AutoReset(env)
    k_reset, k_act = jax.random.split(key)
    states, _ = jax.vmap(auto.reset)(jax.random.split(k_reset, n))

    def body(states, k):
        k_explore, k_random = jax.random.split(k)
        greedy = jax.vmap(lambda s: oracle_action(s, obey_constraint=False, avoid_lava=False))
        random = jax.random.choice(k_random, 6, (n,), p=jnp.asarray(ACTION_PROBS))
        explore = jax.random.uniform(k_explore, (n,)) < 1 / 3
        actions = jnp.where(explore, random, greedy(states)).astype(jnp.int32)
        new, ts = jax.vmap(env.step)(states, actions)
        ref = jax.vmap(paper_rule_step, in_axes=(None, 0, 0))(env, states, actions)
        got = {
            "observation": ts.observation, "reward": ts.reward, "terminated": ts.terminated,
            "truncated": ts.truncated, "info": ts.info, "agent_pos": new.agent_pos,
        }  # fmt: skip
        want = {k: v for k, v in ref.items() if k != "teleported"}
        same = jax.tree.map(lambda a, b: (a == b).reshape(n, -1).all(1), got, want)
        out = {
            "same": jnp.stack(jax.tree.leaves(same)).all(0),
            "violation": ts.info["violation"],
            "teleported": ref["teleported"],
            "lava_violation": ref["info"]["violation"] & ts.terminated & (ts.reward == 0),
        }
        return jax.vmap(auto.step)(states, actions)[0], out

    _, steps = jax.lax.scan(body, states, jax.random.split(k_act, t))
    return steps


@pytest.mark.parametrize("env_id", ["TwoRooms-v0", "TwoRoomsLava-v0", "ThreeRoomsKey-v0"])
def test_the_monitor_judges_the_paper_scenarios_by_their_rule(env_id):
    env = jaxgrid.make(env_id)
    steps = jax.tree.map(np.asarray, _paper_steps(env, jax.random.key(1), 512, 48))
    assert steps["same"].size >= 10_000
    assert steps["same"].all(), np.argwhere(~steps["same"])[:5]
    assert steps["violation"].sum() > 200  # the comparison saw many violations
    if env_id == "TwoRoomsLava-v0":  # and both lava rules
        assert steps["teleported"].sum() > 20 and steps["lava_violation"].sum() > 20


def test_a_zone_bound_below_the_clauses_radius_is_the_callers_and_is_checked():
    grid = np.zeros((5, 5, 3), np.uint8)
    grid[..., 0] = 1
    grid[2, 2] = (9, 0, 0)
    spec = M.encode(L.parse("never stand next to lava"))
    full, _ = M.zone_masks(jnp.asarray(grid), spec)
    flat, _ = M.zone_masks(jnp.asarray(grid), spec, max_radius=0)
    assert int(full[0].sum()) == 5 and int(flat[0].sum()) == 1
    with pytest.raises(ValueError, match="max_radius must be in 0..2"):
        M.zone_masks(jnp.asarray(grid), spec, max_radius=M.MAX_RADIUS + 1)
