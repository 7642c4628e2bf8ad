"""Memory, generated natively, against MiniGrid 3.2.0.

* Layouts: vmapped jaxgrid resets and MiniGrid resets (one seeded RNG stream) are read back
  into the generator's random choices by one function for both sides (the hallway's end, the
  agent's column, the start room's object, the order of the end objects, which end cell
  pays), each marginal compared with a two-sample chi-square test at ``ALPHA``; for every
  hallway end, the walls are MiniGrid's exactly, and the paying cell is next to the end
  object that matches the start room's.
* Steps: natively generated states copied into MiniGrid (``success_pos``/``failure_pos``
  set) and MiniGrid resets converted with ``from_minigrid`` are stepped by both under
  scripted walks to the matching or the other object, then biased random actions (pickup
  included, which acts as toggle), every field at every step; and, one step at a time, from
  states after MiniGrid's termination, where its rule keeps firing.
* Compile-once, refused settings (registry defaults: ``test_differential.py``).
"""

from __future__ import annotations

import collections

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import compare_all, id_param, jax_reset_states, minigrid_resets

import jaxgrid
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import BALL, FORWARD, KEY, LEFT, RIGHT, WALL
from jaxgrid.levels.memory import IDS, Memory

DEFAULT = {"MiniGrid-MemoryS13Random-v0"}
MAX_T = 60


def choices(grids, pos, dirs, success):
    """Check Memory layouts; return their random choices (name -> one value per layout)."""
    out = collections.defaultdict(list)
    walls = {}
    for grid, p, d, s in zip(grids, pos, dirs, success, strict=True):
        kind = grid[..., 0]
        mid = grid.shape[1] // 2
        (end_x,) = {x for x, y in np.argwhere(np.isin(kind, [KEY, BALL])) if x > 1}
        end = end_x - 1
        top, bottom, start = kind[end_x, mid - 2], kind[end_x, mid + 2], kind[1, mid - 1]
        assert {top, bottom} == {KEY, BALL} and start in (KEY, BALL)
        assert (grid[np.isin(kind, [KEY, BALL])][:, 1] == 1).all(), "objects are green"
        assert p[1] == mid and 1 <= p[0] <= end and d == 0
        up = (end_x, mid - 1)
        assert tuple(s) == (up if start == top else (end_x, mid + 1)), "pays at the wrong end"
        seen = walls.setdefault(end, kind == WALL)
        assert (seen == (kind == WALL)).all(), f"walls differ for hallway end {end}"
        out["end"].append(end)
        out["agent_x"].append(p[0])
        out["start"].append(start)
        out["top"].append(top)
        out["pays_up"].append(tuple(s) == up)
    return {k: np.array(v) for k, v in out.items()}, walls


def layouts(env_id, n):
    env = IDS[env_id]()
    st = jax_reset_states(env, 2 * n)
    ours = choices(st.grid, st.agent_pos, st.agent_dir, st.extras.success)
    mg = R.make_reference(env_id)
    *ref, success = minigrid_resets(mg, n, extra=lambda m: m.success_pos)
    return ours, choices(*ref, success)


@pytest.mark.parametrize("env_id", [id_param(i, DEFAULT) for i in IDS])
def test_layouts_are_drawn_as_minigrid_draws_them(env_id):
    (ours, our_walls), (ref, ref_walls) = layouts(env_id, 600 if env_id in DEFAULT else 2000)
    assert set(our_walls) == set(ref_walls)
    for end, mask in ref_walls.items():
        np.testing.assert_array_equal(our_walls[end], mask, err_msg=f"hallway end {end}")
    compare_all(env_id, ours, ref)


def walk(mg, matching: bool) -> list[int]:
    """Actions from MiniGrid's start to the cell next to the matching (or other) object."""
    x, y = (int(c) for c in mg.agent_pos)
    target = mg.success_pos if matching else mg.failure_pos
    turn = LEFT if target[1] < y else RIGHT
    return [FORWARD] * (target[0] - x) + [turn, FORWARD]


def own_step_run(env_id, seeds, native: bool):
    """Native states copied into MiniGrid (``native``) or MiniGrid resets converted; scripted
    walks then random actions; every field compared. Returns the episodes."""
    env = IDS[env_id]()
    states, episodes = [], []
    native_states = jax_reset_states(env, len(seeds), seed=11)
    for b, seed in enumerate(seeds):
        mg = R.make_reference(env_id)
        mg.reset(seed=seed)
        if native:
            state = jax.tree.map(lambda x, b=b: x[b], native_states)
            R.set_minigrid_state(mg, state)
            mg.success_pos = tuple(int(c) for c in state.extras.success)
            mg.failure_pos = tuple(int(c) for c in state.extras.failure)
        else:
            converted, state, _ = from_minigrid(mg)
            assert converted == env
        script = walk(mg, matching=seed % 3 != 2) if seed % 4 else []
        actions = np.concatenate([script, R.draw_actions(seed, 1, MAX_T)[0]])[:MAX_T]
        states.append(jax.tree.map(jnp.asarray, state))
        episodes.append(R.record_episode(mg, actions.astype(np.int32), seed=seed))
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]))
    obs0, outs = R.jax_rollout(env, R.stack(states), actions)
    R.compare(f"{env_id} own step", episodes, obs0, outs)
    return episodes


@pytest.mark.parametrize("native", [True, False], ids=["native", "converted"])
def test_memory_steps_like_minigrid(native):
    episodes = own_step_run("MiniGrid-MemoryS13Random-v0", range(12), native)
    wins, losses = R.outcomes(episodes)
    assert wins >= 4 and losses >= 2, (wins, losses)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
@pytest.mark.parametrize("native", [True, False], ids=["native", "converted"])
def test_memory_steps_like_minigrid_many_seeds(env_id, native):
    episodes = own_step_run(env_id, range(100, 140), native)
    wins, losses = R.outcomes(episodes)
    print(f"{env_id}: {R.coverage(episodes)}, {wins} successes, {losses} failures")
    assert wins >= 10 and losses >= 5


def test_rule_keeps_firing_after_termination_like_minigrid():
    """After MiniGrid's termination each further step pays again (or ends with 0) while the
    agent stays on the cell; every state is converted and stepped once by both."""
    env_id = "MiniGrid-MemoryS9-v0"
    states, episodes, env = [], [], None
    rng = np.random.default_rng(0)
    for seed in range(6):
        mg = R.make_reference(env_id)
        mg.reset(seed=seed)
        for action in walk(mg, matching=seed % 2 == 0):
            mg.step(action)
        for _ in range(8):
            action = int(rng.choice(7, p=R.ACTION_PROBS))
            env, state, _ = from_minigrid(mg)
            states.append(state)
            episodes.append(R.record_episode(mg, np.array([action], np.int32), seed=seed))
    actions = jnp.asarray(np.stack([ep.actions for ep in episodes]))
    obs0, outs = R.jax_rollout(env, R.stack(states), actions)
    R.compare(f"{env_id} after termination", episodes, obs0, outs)
    reward = np.array([ep.steps["reward"][0] for ep in episodes])
    done = np.array([ep.steps["terminated"][0] for ep in episodes])
    assert (done & (reward > 0)).sum() >= 5 and (done & (reward == 0)).sum() >= 5


def test_step_compiles_once():
    env = jaxgrid.make("MiniGrid-MemoryS11-v0")

    @jax.jit
    @chex.assert_max_traces(n=1)
    def step(state, action):
        return env.step(state, action)

    states, _ = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 4))
    for action in range(8):
        states, _ = jax.vmap(step, in_axes=(0, None))(states, action)


@pytest.mark.parametrize(
    "kwargs, field",
    [(dict(width=9, height=8), "height must be odd"), (dict(width=6, height=9), "width")],
)
def test_impossible_sizes_are_refused(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Memory(max_steps=10, **kwargs)
