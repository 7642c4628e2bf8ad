"""FourRooms, the Crossings and DistShift, generated natively, against MiniGrid 3.2.0.

* Layouts: many vmapped jaxgrid resets and many MiniGrid resets (one seeded RNG stream) are
  reduced to what defines the task: agent cell and direction, goal cell, wall gaps and rooms
  (FourRooms), the chosen rivers, each river's opening and the whole obstacle layout
  (Crossings), obstacle counts and the BFS shortest-path length from agent to goal. Each
  quantity passes a two-sample chi-square homogeneity test at ``ALPHA`` (values expected fewer
  than 5 times are pooled into one bin, so sparse tails still count); per-cell occupancy by
  object kind (and by the agent) passes a 2x2 test per cell at ``ALPHA / cells``. Every sample
  is also checked structurally. Seeds are fixed, so outcomes are deterministic.
* Solvable: the BFS reaches the goal (walls and lava blocked) in every reset.
* Steps: natively generated states, copied into MiniGrid, step exactly like MiniGrid with biased
  random actions that mostly turn away from lava (every field, every step, up to MiniGrid's
  episode end; one mismatch fails).
* Registry defaults match MiniGrid's; impossible settings raise ``ValueError`` naming the
  setting, at construction (before any compile).

The default run covers one level of each generator; ``-m slow`` runs every id with more
samples and seeds, and the non-registered settings (other sizes, fixed agent or goal cells).
"""

from __future__ import annotations

import zlib

import jax
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import (
    ALPHA,
    cell_id,
    jax_resets,
    minigrid_resets,
    only,
    same_occupancy,
)
from helpers.xla import batch_reset
from minigrid.core.mission import MissionSpace
from minigrid.envs import CrossingEnv, FourRoomsEnv
from minigrid.minigrid_env import MiniGridEnv
from scipy.stats import chi2_contingency

import jaxgrid
from jaxgrid.constants import (
    EMPTY,
    FORWARD,
    GOAL,
    GOAL_CELL,
    LAVA,
    LAVA_CELL,
    LEFT,
    RIGHT,
    WALL,
    WALL_CELL,
)
from jaxgrid.levels import Crossing, DistShift, FourRooms
from jaxgrid.levels.navigation import IDS

N_JAX, N_MINIGRID = 4000, 2000
SLOW_N_JAX, SLOW_N_MINIGRID = 12000, 6000


# ------------------------------------------------------------------------------ statistics


def chi2_homogeneity(ours, ref) -> tuple[float, float, np.ndarray, np.ndarray]:
    """Two-sample chi-square test on the values of ``ours`` and ``ref``.

    Returns ``(statistic, p, values, counts (2, K))``. Values whose smaller expected count is
    below 5 are pooled into one bin (or, where that bin is itself that rare, into the rarest
    kept value), so the test stays valid on sparse tails.
    """
    ours, ref = np.asarray(ours).ravel(), np.asarray(ref).ravel()
    values, inverse = np.unique(np.concatenate([ours, ref]), return_inverse=True)
    inverse = inverse.ravel()
    k = len(values)
    raw = np.stack(
        [
            np.bincount(inverse[: len(ours)], minlength=k),
            np.bincount(inverse[len(ours) :], minlength=k),
        ]
    )
    share = min(len(ours), len(ref)) / (len(ours) + len(ref))
    kept = raw.sum(axis=0) * share >= 5
    counts = raw[:, kept]
    rare = raw[:, ~kept].sum(axis=1, keepdims=True)
    if rare.sum() * share >= 5 or counts.shape[1] == 0:
        counts = np.concatenate([counts, rare], axis=1)
    elif rare.sum():
        counts[:, counts.sum(axis=0).argmin()] += rare[:, 0]
    if counts.shape[1] < 2:
        return 0.0, 1.0, values, raw
    result = chi2_contingency(counts, correction=False)
    return float(result.statistic), float(result.pvalue), values, raw


def assert_same_distribution(name, ours, ref, alpha=ALPHA):
    stat, p, values, counts = chi2_homogeneity(ours, ref)
    if p <= alpha:
        table = {v: tuple(c) for v, c in zip(values.tolist(), counts.T.tolist(), strict=True)}
        shown = dict(list(table.items())[:40])
        raise AssertionError(f"{name}: chi-square {stat:.1f}, p={p:.2e}; (ours, MiniGrid) {shown}")
    return p


def compare_choices(label, ours, ref):
    """Every quantity of ``ours`` against ``ref``: chi-square for values, per cell for masks.

    Prints (shown with ``pytest -s``) and returns the number of quantities and the smallest
    p-value with its quantity (per-cell p-values multiplied by their number of cells).
    """
    ps = {}
    for name in ours:
        test = same_occupancy if name.startswith("cells:") else assert_same_distribution
        ps[name] = test(f"{label} {name}", ours[name], ref[name])
    worst = min(ps, key=ps.get)
    print(f"{label}: {len(ps)} quantities, smallest p {ps[worst]:.3g} ({worst})")
    return len(ps), ps[worst], worst


# ------------------------------------------------------------------------------ structure


def bfs_lengths(grids, pos):
    """Shortest-path length (moves) from the agent to the goal, -1 if unreachable.

    Empty and goal cells are walkable; walls and lava are not (these levels have nothing else).
    """
    kind = grids[..., 0]
    walkable = (kind == EMPTY) | (kind == GOAL)
    n, w, h = kind.shape
    rows = np.arange(n)
    seen = np.zeros((n, w, h), bool)
    seen[rows, pos[:, 0], pos[:, 1]] = True
    frontier = seen.copy()
    dist = np.full(n, -1)
    for d in range(w * h):
        hit = (frontier & (kind == GOAL)).any(axis=(1, 2)) & (dist < 0)
        dist[hit] = d
        grow = np.zeros_like(frontier)
        grow[:, 1:] |= frontier[:, :-1]
        grow[:, :-1] |= frontier[:, 1:]
        grow[:, :, 1:] |= frontier[:, :, :-1]
        grow[:, :, :-1] |= frontier[:, :, 1:]
        frontier = grow & walkable & ~seen
        seen |= frontier
        if not frontier.any():
            break
    return dist


def common_choices(grids, pos, dirs):
    """Checks every level shares; the quantities every level is compared on."""
    n, w, h, _ = grids.shape
    rows = np.arange(n)
    kind = grids[..., 0]
    for border in (grids[:, 0], grids[:, -1], grids[:, :, 0], grids[:, :, -1]):
        assert (border == WALL_CELL).all()
    assert (grids[kind == WALL] == WALL_CELL).all() and (grids[kind == LAVA] == LAVA_CELL).all()
    assert (grids[kind == GOAL] == GOAL_CELL).all() and (
        grids[kind == EMPTY] == (EMPTY, 0, 0)
    ).all()
    assert np.isin(kind, [EMPTY, WALL, LAVA, GOAL]).all()
    assert (kind[rows, pos[:, 0], pos[:, 1]] != WALL).all()
    assert (kind[rows, pos[:, 0], pos[:, 1]] != LAVA).all()
    goal = only(grids, GOAL)
    dist = bfs_lengths(grids, pos)
    agent = np.zeros((n, w, h), bool)
    agent[rows, pos[:, 0], pos[:, 1]] = True
    return {
        "agent_cell": cell_id(pos, h),
        "agent_dir": dirs,
        "goal_cell": cell_id(goal, h),
        "bfs_length": dist,
        "walls": (kind == WALL).sum(axis=(1, 2)),
        "lava": (kind == LAVA).sum(axis=(1, 2)),
        "cells:wall": kind == WALL,
        "cells:lava": kind == LAVA,
        "cells:goal": kind == GOAL,
        "cells:agent": agent,
    }


def four_rooms_choices(grids, pos, dirs):
    n, w, h, _ = grids.shape
    out = common_choices(grids, pos, dirs)
    assert out["lava"].sum() == 0
    kind = grids[..., 0]
    rw, rh = w // 2, h // 2
    column, row = kind[:, rw], kind[:, :, rh]  # the inner walls, (n, h) and (n, w)
    halves = {
        "gap_top": column[:, 1:rh],
        "gap_bottom": column[:, rh + 1 : h - 1],
        "gap_left": row[:, 1:rw],
        "gap_right": row[:, rw + 1 : w - 1],
    }
    for name, cells in halves.items():
        assert ((cells != WALL).sum(axis=1) == 1).all(), f"not one {name} per layout"
        out[name] = (cells != WALL).argmax(axis=1)
    assert (column[:, rh] == WALL).all() and (kind[:, 1:-1, 1:-1] == WALL).sum() == n * (w + h - 9)
    out["gaps_top_left"] = out["gap_top"] * w + out["gap_left"]
    out["gaps_bottom_right"] = out["gap_bottom"] * w + out["gap_right"]

    def room(xy):  # 0..3, or 4 on an inner wall's gap
        on_wall = (xy[:, 0] == rw) | (xy[:, 1] == rh)
        return np.where(on_wall, 4, (xy[:, 0] > rw) + 2 * (xy[:, 1] > rh))

    goal = np.stack([out["goal_cell"] // h, out["goal_cell"] % h], axis=1)
    assert (out["goal_cell"] != out["agent_cell"]).all()
    out["agent_room"], out["goal_room"] = room(pos), room(goal)
    out["rooms"] = out["agent_room"] * 5 + out["goal_room"]
    out["pose"] = out["agent_cell"] * 4 + dirs
    assert (out["bfs_length"] > 0).all(), "unsolvable FourRooms layout"
    return out


def crossing_choices(grids, pos, dirs):
    """Checks the river structure; returns the rivers, their openings and the whole layout."""
    n, w, h, _ = grids.shape
    out = common_choices(grids, pos, dirs)
    assert (pos == (1, 1)).all() and (dirs == 0).all()
    assert (out["goal_cell"] == cell_id((w - 2, h - 2), h)).all()
    kind = grids[..., 0]
    obstacle = ((kind == WALL) | (kind == LAVA))[:, 1:-1, 1:-1]  # interior only, (n, w-2, h-2)
    assert not ((kind[:, 1:-1, 1:-1] == WALL).any() and (kind == LAVA).any()), "one obstacle kind"
    cols, rows = np.arange(2, w - 2, 2), np.arange(2, h - 2, 2)
    # A river line has all its interior cells blocked but its one opening; any other line is
    # blocked only where it crosses a river (at most len(rows) or len(cols) cells).
    col_count = obstacle[:, cols - 1, :].sum(axis=2)  # (n, len(cols))
    row_count = obstacle[:, :, rows - 1].sum(axis=1)  # (n, len(rows))
    river_v, river_h = col_count >= h - 3, row_count >= w - 3
    assert (col_count[river_v] == h - 3).all() and (row_count[river_h] == w - 3).all()
    rebuilt = np.zeros_like(obstacle)
    rebuilt[:, cols - 1, :] |= river_v[:, :, None]
    rebuilt[:, :, rows - 1] |= river_h[:, None, :]
    openings = rebuilt & ~obstacle
    assert (obstacle & ~rebuilt).sum() == 0, "an obstacle off the chosen rivers"
    assert (openings.sum(axis=(1, 2)) == river_v.sum(axis=1) + river_h.sum(axis=1)).all()
    out["num_rivers"] = river_v.sum(axis=1) + river_h.sum(axis=1)
    out["vertical_rivers"] = river_v.sum(axis=1)
    bits = np.concatenate([river_v, river_h], axis=1)
    out["river_set"] = bits @ (1 << np.arange(bits.shape[1]))
    for k, c in enumerate(cols):  # where each column river opens (0: not a river)
        out[f"opening_x{c}"] = np.where(river_v[:, k], openings[:, c - 1, :].argmax(axis=1) + 1, 0)
    for k, r in enumerate(rows):
        out[f"opening_y{r}"] = np.where(river_h[:, k], openings[:, :, r - 1].argmax(axis=1) + 1, 0)
    out["layout"] = obstacle.reshape(n, -1)  # hashed to ids by layout_ids
    out["cells:opening"] = openings
    assert (out["bfs_length"] > 0).all(), "unsolvable Crossing layout"
    return out


def layout_ids(ours, ref):
    """Replace the ``layout`` bit rows of both samples by shared integer ids."""
    both = np.concatenate([ours["layout"], ref["layout"]])
    _, ids = np.unique(both, axis=0, return_inverse=True)
    ids = ids.ravel()
    ours["layout"], ref["layout"] = ids[: len(ours["layout"])], ids[len(ours["layout"]) :]


def choices_of(env):
    return four_rooms_choices if isinstance(env, FourRooms) else crossing_choices


def check_layouts(label, env, mg, n_jax, n_minigrid, seed=0):
    choose = choices_of(env)
    ours = choose(*jax_resets(env, n_jax, seed))
    ref = choose(*minigrid_resets(mg, n_minigrid, seed))
    if "layout" in ours:
        layout_ids(ours, ref)
    assert set(ours) == set(ref)
    return compare_choices(label, ours, ref)


# ------------------------------------------------------------------------------ layouts

DEFAULT_LAYOUTS = {
    "MiniGrid-FourRooms-v0",
    "MiniGrid-SimpleCrossingS11N5-v0",  # lava crossings step in the default run below
}
RANDOM_IDS = [i for i in IDS if "DistShift" not in i]


@pytest.mark.parametrize("env_id", sorted(DEFAULT_LAYOUTS))
def test_layout_distribution(env_id):
    check_layouts(env_id, jaxgrid.make(env_id), R.make_reference(env_id), N_JAX, N_MINIGRID)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", RANDOM_IDS)
def test_layout_distribution_many_samples(env_id):
    env, mg = jaxgrid.make(env_id), R.make_reference(env_id)
    check_layouts(env_id, env, mg, SLOW_N_JAX, SLOW_N_MINIGRID, seed=1)


class SizedFourRooms(FourRoomsEnv):
    """MiniGrid's FourRooms generator at another size (its constructor fixes 19x19)."""

    def __init__(self, width, height, **kwargs):
        self._agent_default_pos = kwargs.pop("agent_pos", None)
        self._goal_default_pos = kwargs.pop("goal_pos", None)
        MiniGridEnv.__init__(
            self,
            mission_space=MissionSpace(mission_func=FourRoomsEnv._gen_mission),
            width=width,
            height=height,
            max_steps=100,
        )


VARIANTS = {  # label: (jaxgrid env, MiniGrid env)
    "FourRooms 11x9": (
        lambda: FourRooms(width=11, height=9, max_steps=100),
        lambda: SizedFourRooms(11, 9),
    ),
    "FourRooms agent_pos": (
        lambda: FourRooms(width=19, height=19, max_steps=100, agent_start=(4, 13)),
        lambda: FourRoomsEnv(agent_pos=(4, 13)),
    ),
    "FourRooms goal_pos": (
        lambda: FourRooms(width=7, height=7, max_steps=100, goal_start=(2, 2)),
        lambda: SizedFourRooms(7, 7, goal_pos=(2, 2)),  # the agent may start on the goal
    ),
    "Crossing S7N2 lava": (
        lambda: Crossing(width=7, height=7, max_steps=196, num_crossings=2),
        lambda: CrossingEnv(size=7, num_crossings=2),
    ),
    "Crossing S13N7 wall": (
        lambda: Crossing(width=13, height=13, max_steps=676, num_crossings=7, obstacle="wall"),
        lambda: CrossingEnv(size=13, num_crossings=7, obstacle_type="wall"),
    ),
    "Crossing S5N0": (
        lambda: Crossing(width=5, height=5, max_steps=100, num_crossings=0),
        lambda: CrossingEnv(size=5, num_crossings=0),
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("label", list(VARIANTS))
def test_other_settings_match_minigrids_generator(label):
    make_ours, make_ref = VARIANTS[label]
    env, mg = make_ours(), make_ref()
    if label == "FourRooms goal_pos":  # the agent is drawn before the goal is put down
        grids, pos, dirs = jax_resets(env, N_JAX)
        ref_grids, ref_pos, ref_dirs = minigrid_resets(mg, N_MINIGRID)
        assert (grids[:, 2, 2] == GOAL_CELL).all() and (ref_grids[:, 2, 2] == GOAL_CELL).all()
        on_goal = lambda p: (p == (2, 2)).all(axis=1)
        assert on_goal(pos).any() and on_goal(ref_pos).any()
        assert_same_distribution(
            label, cell_id(pos, 7) * 4 + dirs, cell_id(ref_pos, 7) * 4 + ref_dirs
        )
        same_occupancy(label, grids[..., 0] == WALL, ref_grids[..., 0] == WALL)
        return
    check_layouts(label, env, mg, N_JAX, N_MINIGRID)


def test_non_square_crossing_puts_rivers_on_columns_and_rows():
    # 11x9: four candidate columns (x = 2, 4, 6, 8) and three rows (y = 2, 4, 6).
    env = Crossing(width=11, height=9, max_steps=100, num_crossings=6, obstacle="wall")
    out = crossing_choices(*jax_resets(env, 512))
    assert (out["num_rivers"] == 6).all()
    assert set(np.unique(out["vertical_rivers"]).tolist()) == {3, 4}
    assert (out["opening_x8"] > 0).any() and "opening_y8" not in out


# ------------------------------------------------------------------------------ DistShift


@pytest.mark.parametrize("env_id", ["MiniGrid-DistShift1-v0", "MiniGrid-DistShift2-v0"])
def test_dist_shift_is_minigrids_layout(env_id):
    grids, pos, dirs = jax_resets(jaxgrid.make(env_id), 8)
    ref_grids, ref_pos, ref_dirs = minigrid_resets(R.make_reference(env_id), 2)
    assert (ref_grids == ref_grids[0]).all()
    assert (
        (grids == ref_grids[0]).all() and (pos == ref_pos[0]).all() and (dirs == ref_dirs[0]).all()
    )
    assert (bfs_lengths(grids[:1], pos[:1]) > 0).all()


def test_dist_shift_random_start_matches_place_agent():
    env = jaxgrid.make("MiniGrid-DistShift2-v0", agent_start=None)
    mg = R.make_reference("MiniGrid-DistShift2-v0", agent_start_pos=None)
    grids, pos, dirs = jax_resets(env, N_JAX)
    ref_grids, ref_pos, ref_dirs = minigrid_resets(mg, N_MINIGRID)
    assert (grids == ref_grids[0]).all() and (ref_grids == ref_grids[0]).all()
    assert (grids[np.arange(len(pos)), pos[:, 0], pos[:, 1], 0] == EMPTY).all()
    assert_same_distribution(
        "DistShift2 random start", cell_id(pos, 7) * 4 + dirs, cell_id(ref_pos, 7) * 4 + ref_dirs
    )
    assert (bfs_lengths(grids, pos) > 0).all()


# ------------------------------------------------------------------------------ solvable


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_every_episode_is_solvable(env_id):
    grids, pos, _ = jax_resets(jaxgrid.make(env_id), 20000, seed=2)
    dist = bfs_lengths(grids, pos)
    assert (dist > 0).all(), f"{env_id}: {(dist <= 0).sum()} of {len(dist)} resets unsolvable"


# ------------------------------------------------------------------------------ steps

SEEDS, SLOW_SEEDS, MAX_T = 8, 40, 200  # MAX_T: steps per episode in the default run


def lava_shy(mg, state, actions, rng):
    """``actions`` with 90% of the forward moves into lava turned into a random turn.

    Replayed in MiniGrid from ``state``: random actions die in lava within a few dozen steps,
    and the shy ones reach much further (the goal too) while still entering lava now and then.
    """
    actions = actions.copy()
    R.set_minigrid_state(mg, state)
    for t in range(len(actions)):
        front = mg.grid.get(*mg.front_pos)
        if actions[t] == FORWARD and front is not None and front.type == "lava":
            if rng.random() < 0.9:
                actions[t] = rng.choice([LEFT, RIGHT])
        _, _, terminated, truncated, _ = mg.step(int(actions[t]))
        if terminated or truncated:
            break
    return actions


def native_run(env_id, num, key_seed, num_steps=MAX_T, **kw):
    """Reset natively, copy each state into MiniGrid, step both with the same actions.

    Episodes run ``min(num_steps, max_steps)`` steps unless MiniGrid ends them earlier.
    """
    env = jaxgrid.make(env_id)
    mg = R.make_reference(env_id)
    cfg = R.config_env(env)
    states, ts = batch_reset(env, jax.random.split(jax.random.PRNGKey(key_seed), num))
    num_steps = min(env.max_steps, num_steps)
    seed = zlib.crc32(env_id.encode()) + key_seed
    actions = R.draw_actions(seed, num, num_steps)
    rng = np.random.default_rng(seed)
    episodes = []
    for b in range(num):
        state = jax.tree.map(lambda x, b=b: x[b], states)
        mg.reset(seed=b)  # anything; then overwrite with our state
        actions[b] = lava_shy(mg, state, actions[b], rng)
        R.set_minigrid_state(mg, state)
        episodes.append(R.record_episode(mg, actions[b], seed=b, **kw))
        np.testing.assert_array_equal(ts.observation["image"][b], episodes[-1].obs0)
    obs0, outs = R.jax_rollout(cfg, states, jax.numpy.asarray(actions))
    R.compare(f"native {env_id} key {key_seed}", episodes, obs0, outs)  # raises on a mismatch
    return episodes


# DistShift's one layout equals MiniGrid's (tested above), so the differential tests of converted
# MiniGrid levels step it already; it steps natively with ``-m slow``.
NATIVE_DEFAULT = ["MiniGrid-FourRooms-v0", "MiniGrid-LavaCrossingS9N2-v0"]


@pytest.mark.parametrize("env_id", NATIVE_DEFAULT)
def test_native_levels_step_like_minigrid(env_id):
    episodes = native_run(env_id, SEEDS, key_seed=0)
    assert sum(ep.length for ep in episodes) >= SEEDS


@pytest.mark.slow
@pytest.mark.parametrize("env_id", list(IDS))
def test_native_levels_step_like_minigrid_many_seeds(env_id):
    seeds = SLOW_SEEDS * (3 if env_id == "MiniGrid-FourRooms-v0" else 1)  # 100-step episodes
    episodes = native_run(env_id, seeds, 11, num_steps=10**6, encode_every_step=True)
    stats = R.coverage(episodes)
    print(f"{env_id}: {stats}")
    assert stats["steps"] >= 30 * 150, stats
    assert stats["goal"] > 0 and stats["truncated"] > 0, stats
    if "Lava" in env_id or "DistShift" in env_id:
        assert stats["lava"] > 0, stats


# ------------------------------------------------------------------------------ registry


@pytest.mark.parametrize("env_id", list(IDS))
def test_make_builds_minigrids_defaults(env_id):
    """Grid size, max_steps, view size and see_through_walls as MiniGrid sets them."""
    env = jaxgrid.make(env_id)
    assert env_id in jaxgrid.registered_ids() and isinstance(env, (FourRooms, Crossing, DistShift))
    mg = R.make_reference(env_id)
    ours = (env.width, env.height, env.max_steps, env.view_size, env.see_through_walls)
    assert ours == (mg.width, mg.height, mg.max_steps, mg.agent_view_size, mg.see_through_walls)
    if isinstance(env, Crossing):
        assert env.num_crossings == mg.num_crossings
        assert env.obstacle == mg.obstacle_type.__name__.lower()
    if isinstance(env, DistShift):
        assert env.strip2_row == mg.strip2_row


# ------------------------------------------------------------------------------ validation


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: FourRooms(width=18, height=19, max_steps=9), r"FourRooms\.width must be odd"),
        (
            lambda: FourRooms(width=19, height=4, max_steps=9),
            r"FourRooms\.height must be at least 5",
        ),
        (
            lambda: FourRooms(width=9, height=9, max_steps=9, agent_start=(0, 3)),
            r"FourRooms\.agent_start",
        ),
        (
            lambda: FourRooms(width=9, height=9, max_steps=9, goal_start=(3, 8)),
            r"FourRooms\.goal_start",
        ),
        (lambda: Crossing(width=9, height=10, max_steps=9), r"Crossing\.height must be odd"),
        (lambda: Crossing(width=3, height=9, max_steps=9), r"Crossing\.width must be at least 5"),
        (
            lambda: Crossing(width=9, height=9, max_steps=9, num_crossings=7),
            r"Crossing\.width must be at least 11 \(7 rivers",
        ),
        (
            lambda: Crossing(width=9, height=9, max_steps=9, num_crossings=-1),
            r"Crossing\.num_crossings",
        ),
        (lambda: Crossing(width=9, height=9, max_steps=9, obstacle="ball"), r"Crossing\.obstacle"),
        (lambda: DistShift(width=3, height=7, max_steps=9), r"DistShift\.width must be at least 4"),
        (
            lambda: DistShift(width=9, height=6, max_steps=9, strip2_row=5),
            r"DistShift\.height must be at least 7",
        ),
        (lambda: DistShift(width=9, height=7, max_steps=9, strip2_row=0), r"DistShift\.strip2_row"),
        (
            lambda: DistShift(width=9, height=7, max_steps=9, agent_start=(3, 2)),
            r"DistShift\.agent_start",
        ),
        (
            lambda: DistShift(width=9, height=7, max_steps=9, agent_start_dir=4),
            r"DistShift\.agent_start_dir",
        ),
    ],
)
def test_impossible_settings_raise_naming_the_setting(make, message):
    with pytest.raises(ValueError, match=message):
        make()


@pytest.mark.parametrize(
    "env_id, overrides, message",
    [
        ("MiniGrid-FourRooms-v0", dict(width=20), r"FourRooms\.width must be odd"),
        (
            "MiniGrid-LavaCrossingS11N5-v0",
            dict(width=7, height=7),
            r"Crossing\.width must be at least 9",
        ),
        (
            "MiniGrid-SimpleCrossingS9N1-v0",
            dict(num_crossings=9),
            r"Crossing\.width must be at least 13",
        ),
        ("MiniGrid-DistShift2-v0", dict(height=6), r"DistShift\.height must be at least 7"),
    ],
)
def test_impossible_overrides_raise_at_make(env_id, overrides, message):
    with pytest.raises(ValueError, match=message):
        jaxgrid.make(env_id, **overrides)


def test_four_rooms_agent_start_on_a_wall_clears_it():
    env = FourRooms(width=19, height=19, max_steps=100, agent_start=(9, 4))
    grids, pos, dirs = jax_resets(env, 256)
    assert (pos == (9, 4)).all() and (grids[:, 9, 4, 0] == EMPTY).all()
    assert set(np.unique(dirs).tolist()) == {0, 1, 2, 3}
    assert ((grids[..., 0] == GOAL) & ~(np.arange(19)[:, None] == 9)).any()
    mg = FourRoomsEnv(agent_pos=(9, 4))
    mg.reset(seed=0)
    assert mg.grid.get(9, 4) is None  # MiniGrid does the same
