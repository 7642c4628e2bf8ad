"""Dynamic-Obstacles, generated natively with its moving balls, against MiniGrid 3.2.0.

* Layouts: vmapped jaxgrid resets and MiniGrid resets (one seeded RNG stream): the agent's
  cell and direction, the balls' cells (per-cell occupancy), the goal, compared with
  two-sample chi-square tests at ``ALPHA``.
* Steps: MiniGrid draws its balls' moves from its own RNG, so each MiniGrid step is replayed
  here with MiniGrid's moves: every move must be one jaxgrid's sampler can draw (a cell its
  ``allowed`` mask admits, given the balls moved before; staying only when none is), and
  ``step_after_moves`` with those moves must give every field MiniGrid gives (image,
  direction, reward, terminated, truncated, grid, agent cell), every step, from natively
  generated states copied into MiniGrid and from MiniGrid resets converted with
  ``from_minigrid``, on past the episode's end as MiniGrid steps on. Actions are biased
  towards ``forward`` and include 3..6 (left in MiniGrid). The runs must hit balls and
  walls; a crowded level has balls with no cell to move to, which stay in both.
* The moves' distribution: from fixed states, jaxgrid's sampled moves against MiniGrid's
  (reseeded each time), joint cells of all balls, two-sample chi-square.
* Actions outside ``0..2``, negative ones included, step exactly as ``left``.
* The full step (moves drawn from ``state.key``) compiles once and runs under
  ``BatchedAutoReset``, reset and step compile within 5 s (slow); obstacle counts as
  MiniGrid reduces them; refused settings.
"""

from __future__ import annotations

import collections

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import (
    compare_all,
    compare_distributions,
    id_param,
    jax_reset_states,
    minigrid_resets,
)
from helpers.xla import compile_seconds

import jaxgrid
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import BALL, EMPTY_CELL, GOAL
from jaxgrid.levels.dynamic import BALL_CELL, IDS, DynamicObstacles
from jaxgrid.wrappers import BatchedAutoReset

DEFAULT = {"MiniGrid-Dynamic-Obstacles-Random-6x6-v0"}
ACTION_P = np.array([0.15, 0.15, 0.5, 0.05, 0.05, 0.05, 0.05])


def layout_choices(grids, pos, dirs):
    out = collections.defaultdict(list)
    for grid, p, d in zip(grids, pos, dirs, strict=True):
        kind = grid[..., 0]
        w, h = kind.shape
        assert kind[w - 2, h - 2] == GOAL and kind[tuple(p)] != BALL
        out["agent"].append(p[0] * h + p[1])
        out["dir"].append(d)
        out["balls"].append((kind == BALL).sum())
    out = {k: np.array(v) for k, v in out.items()}
    out["cells:balls"] = grids[..., 0] == BALL
    return out


@pytest.mark.parametrize("env_id", [id_param(i, DEFAULT) for i in IDS])
def test_layouts_are_drawn_as_minigrid_draws_them(env_id):
    n = 800 if env_id in DEFAULT else 2000
    env = IDS[env_id]()
    st = jax_reset_states(env, 2 * n)
    ours = layout_choices(st.grid, st.agent_pos, st.agent_dir)
    for grid, cells in zip(st.grid, st.extras, strict=True):  # extras: the balls, in order
        assert (grid[cells[:, 0], cells[:, 1], 0] == BALL).all()
    compare_all(env_id, ours, layout_choices(*minigrid_resets(R.make_reference(env_id), n)))


def copy_into(mg, state):
    """Make MiniGrid hold the native ``state``, its ``obstacles`` the balls in order."""
    R.set_minigrid_state(mg, state)
    mg.obstacles = []
    for x, y in np.asarray(state.extras):
        ball = mg.grid.get(int(x), int(y))
        ball.cur_pos = np.array((x, y))
        mg.obstacles.append(ball)


def replay(env_id, seeds, native, steps, env=None):
    """Step MiniGrid and replay each step here with MiniGrid's moves; returns counters.
    ``env`` (native starts only) replaces the id's level, e.g. with more balls."""
    env = env or IDS[env_id]()
    after, allowed = jax.jit(env.step_after_moves), jax.jit(env.allowed)
    counts = collections.Counter()
    starts = jax_reset_states(env, len(seeds), seed=3)
    rng = np.random.default_rng(len(seeds))
    for b, seed in enumerate(seeds):
        mg = R.make_reference(env_id)
        mg.reset(seed=seed)
        if native:
            state = jax.tree.map(lambda x, b=b: jnp.asarray(x[b]), starts)
            copy_into(mg, state)
        else:
            converted, state, _ = from_minigrid(mg)
            assert converted == env
        for t, action in enumerate(rng.choice(7, size=steps, p=ACTION_P)):
            old = [tuple(int(c) for c in o.cur_pos) for o in mg.obstacles]
            obs, reward, terminated, truncated, _ = mg.step(int(action))
            new = [tuple(int(c) for c in o.cur_pos) for o in mg.obstacles]
            grid = np.asarray(state.grid).copy()
            for was, now in zip(old, new, strict=True):
                mask = np.asarray(allowed(grid, np.array(was), state.agent_pos))
                if mask.any():
                    assert mask[now], f"seed {seed} step {t}: ball {was}->{now} not allowed"
                    grid[now], grid[was] = grid[was], (1, 0, 0)
                else:
                    assert now == was, f"seed {seed} step {t}: ball {was} moved with no cell"
                    counts["stuck ball"] += 1
            state, ts = after(state, int(action), jnp.asarray(grid), jnp.asarray(new))
            where = f"{env_id} seed {seed} step {t} action {action}"
            np.testing.assert_array_equal(np.asarray(ts.observation["image"]), obs["image"], where)
            assert int(ts.observation["direction"]) == obs["direction"], where
            assert float(ts.reward) == pytest.approx(reward, abs=1e-6), where
            assert (bool(ts.terminated), bool(ts.truncated)) == (terminated, truncated), where
            np.testing.assert_array_equal(np.asarray(state.grid), mg.grid.encode(), where)
            assert tuple(np.asarray(state.agent_pos)) == tuple(mg.agent_pos), where
            assert mg.carrying is None and (np.asarray(state.carrying) == EMPTY_CELL).all(), where
            counts["steps"] += 1
            if terminated or truncated:  # both step on after the end, as MiniGrid allows
                counts["hit" if reward < 0 else "goal" if reward > 0 else "other"] += 1
    return counts


@pytest.mark.parametrize("native", [True, False], ids=["native", "converted"])
def test_steps_replay_minigrids_moves(native):
    counts = replay("MiniGrid-Dynamic-Obstacles-Random-6x6-v0", range(16), native, 60)
    assert counts["hit"] >= 5, counts


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
@pytest.mark.parametrize("native", [True, False], ids=["native", "converted"])
def test_steps_replay_minigrids_moves_many_seeds(env_id, native):
    counts = replay(env_id, range(100, 130), native, 200)
    print(env_id, dict(counts))
    assert counts["hit"] >= 30 and counts["steps"] == 30 * 200


def test_crowded_balls_stay_or_take_the_one_free_cell_like_minigrid():
    """Six balls in a 5 x 5 level leave one free cell: balls next to it take it, the others
    have nowhere to go and stay (MiniGrid's place_obj gives up, the ball keeps its cell)."""
    crowded = IDS["MiniGrid-Dynamic-Obstacles-5x5-v0"]().replace(n_obstacles=6)
    counts = replay("MiniGrid-Dynamic-Obstacles-5x5-v0", range(12), True, 10, env=crowded)
    assert counts["stuck ball"] >= 12 and counts["steps"] >= 12, counts


def joint_moves_minigrid(env_id, state, n):
    mg = R.make_reference(env_id)
    mg.reset(seed=0)
    out = []
    for i in range(n):
        copy_into(mg, state)
        mg.np_random = np.random.default_rng(i)
        mg.step(0)  # turn left: only the balls move on the grid
        out.append(str([tuple(int(c) for c in o.cur_pos) for o in mg.obstacles]))
    return np.array(out)


def joint_moves_jaxgrid(env, state, n):
    """``n`` sampled moves as strings; each moved grid must hold the balls exactly at the
    returned cells and be otherwise ``state``'s grid."""
    u = jax.random.uniform(jax.random.PRNGKey(1), (n, env.n_obstacles))
    grids, cells = jax.jit(jax.vmap(env.move_obstacles, in_axes=(None, 0)))(state, u)
    grids, cells = np.asarray(grids), np.asarray(cells)
    rest = np.asarray(state.grid).copy()
    rest[rest[..., 0] == BALL] = EMPTY_CELL
    for grid, row in zip(grids, cells, strict=True):
        expected = rest.copy()
        expected[row[:, 0], row[:, 1]] = BALL_CELL
        assert len({tuple(c) for c in row}) == len(row)
        np.testing.assert_array_equal(grid, expected)
    return np.array([str([tuple(int(c) for c in b) for b in row]) for row in cells])


@pytest.mark.parametrize("env_id", ["MiniGrid-Dynamic-Obstacles-6x6-v0"])
def test_moves_are_drawn_as_minigrid_draws_them(env_id):
    env = IDS[env_id]()
    states = jax_reset_states(env, 3, seed=9)
    for b in range(3):
        state = jax.tree.map(lambda x, b=b: jnp.asarray(x[b]), states)
        ref = joint_moves_minigrid(env_id, state, 1500)
        ours = joint_moves_jaxgrid(env, state, 3000)
        compare_distributions(f"{env_id} state {b} moves", ours, ref)


def test_full_step_compiles_once_and_runs_batched():
    env = jaxgrid.make("MiniGrid-Dynamic-Obstacles-8x8-v0")
    assert env.num_actions == 3

    @jax.jit
    @chex.assert_max_traces(n=1)
    def step(states, actions):
        return BatchedAutoReset(env).step(states, actions)

    states, _ = BatchedAutoReset(env).reset(jax.random.split(jax.random.PRNGKey(0), 64))
    ended = 0
    for t in range(40):
        actions = jax.random.randint(jax.random.PRNGKey(t), (64,), 0, 3)
        states, ts = step(states, actions)
        ended += int(ts.terminated.sum())
        balls = np.asarray(states.grid[..., 0] == BALL).sum(axis=(1, 2))
        assert (balls == env.n_obstacles).all()
    assert ended > 20


def test_out_of_range_actions_act_as_left():
    """MiniGrid turns ``action >= 3`` into ``left`` and raises on negative actions (after
    moving the balls); here every action outside ``0..2`` is ``left``, same key, same moves."""
    env = IDS["MiniGrid-Dynamic-Obstacles-8x8-v0"]()
    state, _ = env.reset(jax.random.PRNGKey(4))
    step = jax.jit(env.step)
    left = step(state, 0)
    assert int(left[0].agent_dir) != int(step(state, 1)[0].agent_dir)  # the check can fail
    for action in (-7, -1, 3, 6, 7, 100):
        pairs = zip(jax.tree.leaves(left), jax.tree.leaves(step(state, action)), strict=True)
        assert all(np.array_equal(a, b) for a, b in pairs), action


def test_obstacle_counts_are_minigrids():
    for env_id in IDS:
        mg = R.make_reference(env_id)
        assert jaxgrid.make(env_id).n_obstacles == mg.n_obstacles, env_id


@pytest.mark.parametrize(
    "kwargs, message",
    [
        (dict(n_obstacles=-1), "n_obstacles"),
        (dict(n_obstacles=8), r"width must be at least 6 \(the agent, the goal and 8 balls"),
        (dict(agent_start=(3, 3)), "agent_start"),
        (dict(agent_start_dir=4), "agent_start_dir"),
    ],
)
def test_bad_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DynamicObstacles(width=5, height=5, max_steps=10, **kwargs)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_compile_seconds(env_id):
    reset, _, step = compile_seconds(IDS[env_id](), 64)
    assert reset + step < 5
