"""The BFS oracle on the paper's scenarios: every episode of the shared batch of resets is
solvable without a violation, and ignoring the constraint would violate it often (printed with
``pytest -s``); the oracle also solves a classic level with keys and locked doors."""

from __future__ import annotations

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.scenario_resets import SCENARIOS, SEED, N, resets
from helpers.xla import OPTIMISED

import jaxgrid
from jaxgrid.constants import CLOSED, EMPTY_CELL, GOAL, KEY, LOCKED
from jaxgrid.oracle import distance_field, passable_cells, rollout_oracle

# Thousands of oracle episodes (a BFS per step) are run-time bound: compiled with full
# optimisation. The oracle's flags stay traced, so each scenario compiles once.
_rollout_oracle = jax.jit(rollout_oracle, static_argnums=2, compiler_options=OPTIMISED)


@functools.cache
def oracle_results(name: str, obey_constraint: bool = True, avoid_lava: bool = True):
    """Oracle rollouts of the ``N`` episodes of :func:`resets` and their wall time."""
    env = jaxgrid.make(name)
    t0 = time.perf_counter()
    out = _rollout_oracle(
        env, jax.random.PRNGKey(SEED), N, obey_constraint=obey_constraint, avoid_lava=avoid_lava
    )
    out = jax.tree.map(np.asarray, out)
    return out, time.perf_counter() - t0


# TwoRooms by default; the other scenarios' BFS runs add 14-25 s per test, under -m slow
ORACLE_CASES = [n if n == "TwoRooms-v0" else pytest.param(n, marks=pytest.mark.slow)
                for n in SCENARIOS]  # fmt: skip


@pytest.mark.parametrize("name", ORACLE_CASES)
def test_oracle_solves_every_episode_without_violation(name):
    r, seconds = oracle_results(name)
    print(
        f"\n{name}: oracle success {r['success'].mean():.4f}, episodes with a violation "
        f"{(r['violations'] > 0).mean():.4f}, mean length {r['length'].mean():.1f} "
        f"(max {r['length'].max()}), {N} episodes in {seconds:.1f} s (compile included)"
    )
    assert r["done"].all()
    assert r["success"].all()
    assert (r["violations"] == 0).all()
    np.testing.assert_array_equal(r["door_colour"], resets(name)[0].extras.constraint.door_colour)
    assert set(np.unique(r["constraint_type"])) == (
        {1, 2, 3, 4, 5} if name == "TwoRoomsLava-v0" else {1, 2, 3}
    )


def test_oracle_solves_doorkey():
    """The oracle is generic: keys and locked doors of a classic level, no constraint."""
    r = rollout_oracle(jaxgrid.make("MiniGrid-DoorKey-8x8-v0"), jax.random.PRNGKey(0), 500)
    assert np.asarray(r["success"]).all()
    assert (np.asarray(r["constraint_type"]) == 0).all()


def _forced_detour(name: str) -> np.ndarray:
    """bool (N,): the constraint makes the agent's shortest route to the goal longer, i.e.
    every shortest route violates it (on the layouts :func:`oracle_results` plays).

    Distances in moves from the start, with locked doors treated as unlocked and the key
    removed (every route crosses the locked door, so the key detour is the same for both);
    lava avoided.
    """
    states, _ = resets(name)
    n = N

    def one(grid, agent, forbidden):
        unlocked = grid.at[..., 2].set(jnp.where(grid[..., 2] == LOCKED, CLOSED, grid[..., 2]))
        unlocked = jnp.where((grid[..., :1] == KEY), jnp.asarray(EMPTY_CELL), unlocked)
        passable = passable_cells(unlocked, jnp.asarray(EMPTY_CELL), forbidden)
        dist = distance_field(grid[..., 0] == GOAL, passable)
        return dist[agent[0], agent[1]]

    f = jax.jit(jax.vmap(one), compiler_options=OPTIMISED)  # a BFS per episode: run-time bound
    grid, agent = jnp.asarray(states.grid), jnp.asarray(states.agent_pos)
    free = f(grid, agent, jnp.full((n,), -1, jnp.int32))
    constrained = f(grid, agent, jnp.asarray(states.extras.constraint.door_colour))
    free, constrained = np.asarray(free), np.asarray(constrained)
    assert (constrained < states.grid.shape[1] * states.grid.shape[2]).all()  # solvable
    return constrained > free


@pytest.mark.parametrize("name", ORACLE_CASES)
def test_unconstrained_shortest_route_often_violates(name):
    """The constraint matters: the BFS oracle ignoring it violates it in a good share of
    episodes (same layouts as the constrained run). Printed with ``pytest -s``."""
    r, _ = oracle_results(name, obey_constraint=False)
    v = r["violations"] > 0
    ctype = r["constraint_type"]
    by_type = ", ".join(f"type {t}: {v[ctype == t].mean():.3f}" for t in np.unique(ctype))
    forced = _forced_detour(name)
    print(
        f"\n{name}: unconstrained oracle (doors ignored, lava avoided) violates in "
        f"{v.mean():.3f} of {N} episodes ({by_type}); the constraint lengthens the "
        f"shortest route (every shortest route violates) in {forced.mean():.3f}"
    )
    assert r["success"].all()
    assert 0.2 < v.mean() < 0.8
    assert forced.mean() > 0.1
    assert not (forced & ~v).any()  # a forced detour is always a violation when ignored
    if name == "TwoRoomsLava-v0":
        # Lava passable too: entering lava counts only where the constraint forbids it.
        r2, _ = oracle_results(name, obey_constraint=False, avoid_lava=False)
        v2, lava = r2["violations"] > 0, r2["forbids_lava"]
        print(
            f"{name}: unconstrained oracle through lava violates in {v2.mean():.3f} of "
            f"episodes ({v2[lava].mean():.3f} when lava is forbidden, {v2[~lava].mean():.3f} "
            f"when not); success {r2['success'].mean():.3f}"
        )
        assert (r2["success"] | (v2 & lava)).all()  # failures are lava deaths
        assert v2[lava].mean() > v[lava].mean()
