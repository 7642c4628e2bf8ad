"""Layout distributions of the classic levels against MiniGrid 3.2.0's own generators.

Many vmapped jaxgrid resets and many MiniGrid resets (one seeded RNG stream) are reduced to the
random choices each generator makes (split column, door row, agent cell and direction, key
cell, lava gap); each marginal (and a few joints) must (a) have the same support and (b) pass a
two-sample chi-square homogeneity test at ``ALPHA`` (``helpers.layout_stats``). All seeds are
fixed, so the outcome is deterministic; at these sizes every marginal passed with p > 0.05.
Sensitivity was checked when the test was written: shifting a support by one (every value + 1,
or only the largest, e.g. the door row drawn from ``[1, w - 1)``) fails every marginal, by the
support check or with p < 1e-6, and moving 10% of the samples of a low-cardinality marginal
(split column, door row, direction, gap) to the neighbouring value fails with p < 1e-4.
Every sample is also checked structurally (the fixed parts: borders, goal, door colour/state,
one key on the agent's side and not under the agent, lava strip).
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import (
    assert_same_support_and_chi2,
    cell_id,
    jax_resets,
    minigrid_resets,
    only,
)
from minigrid.core.mission import MissionSpace
from minigrid.envs.doorkey import DoorKeyEnv
from minigrid.minigrid_env import MiniGridEnv

import jaxgrid
from jaxgrid.constants import DOOR, EMPTY, GOAL, GREEN, GREY, KEY, LAVA, LOCKED, RED, WALL, YELLOW
from jaxgrid.levels import DoorKey

N_JAX = 6000
N_MINIGRID = 3000


def check_border_and_goal(grids):
    w, h = grids.shape[1:3]
    wall = np.array([WALL, GREY, 0])
    for border in (grids[:, 0], grids[:, -1], grids[:, :, 0], grids[:, :, -1]):
        assert (border == wall).all()
    assert (grids[:, w - 2, h - 2] == (GOAL, GREEN, 0)).all()


# --------------------------------------------------------------------------------- DoorKey


def doorkey_choices(grids, pos, dirs):
    """Check structure; return the generator's random choices."""
    n, w, h, _ = grids.shape
    check_border_and_goal(grids)
    door = only(grids, DOOR)
    key = only(grids, KEY)
    split, door_y = door[:, 0], door[:, 1]
    rows = np.arange(n)
    assert (grids[rows, split, door_y] == (DOOR, YELLOW, LOCKED)).all()
    assert (grids[rows, key[:, 0], key[:, 1]] == (KEY, YELLOW, 0)).all()
    column = grids[rows, split]  # (n, h, 3): the splitting wall
    is_door = np.arange(h)[None, :] == door_y[:, None]
    assert ((column[..., 0] == WALL) | is_door).all()
    assert (key[:, 0] < split).all() and (pos[:, 0] < split).all()
    assert (pos[:, 0] >= 1).all() and (pos[:, 1] >= 1).all() and (pos[:, 1] <= h - 2).all()
    assert (key != pos).any(axis=1).all(), "the key never lies under the agent"
    assert (grids[rows, pos[:, 0], pos[:, 1], 0] == EMPTY).all()
    off_wall = np.arange(w)[None, :] != split[:, None]  # (n, w)
    interior = (grids[..., 0] != EMPTY) & off_wall[..., None]
    assert (interior[:, 1 : w - 1, 1 : h - 1].sum(axis=(1, 2)) == 2).all(), "key + goal only"
    return {
        "split": split,
        "door_row": door_y,
        "agent_cell": cell_id(pos, h),
        "agent_dir": dirs,
        "key_cell": cell_id(key, h),
        "split_and_door": split * h + door_y,
        "split_and_agent": split * w * h + cell_id(pos, h),
    }


# One size of each generator in the default run; the other with ``-m slow``.
@pytest.mark.parametrize("size", [pytest.param(5, marks=pytest.mark.slow), 8])
def test_doorkey_layout_distribution(size):
    env_id = f"MiniGrid-DoorKey-{size}x{size}-v0"
    ours = doorkey_choices(*jax_resets(jaxgrid.make(env_id), N_JAX))
    ref = doorkey_choices(*minigrid_resets(R.make_reference(env_id), N_MINIGRID))
    for name in ours:
        assert_same_support_and_chi2(f"{env_id} {name}", ours[name], ref[name])


class RectDoorKey(DoorKeyEnv):
    """MiniGrid's DoorKey generator on a non-square grid (its API only takes ``size``)."""

    def __init__(self, width, height):
        MiniGridEnv.__init__(
            self,
            mission_space=MissionSpace(mission_func=DoorKeyEnv._gen_mission),
            width=width,
            height=height,
            max_steps=10 * width * height,
        )


@pytest.mark.parametrize("width, height", [(10, 6), (6, 10)])
def test_doorkey_non_square_door_row(width, height):
    grids, pos, dirs = jax_resets(DoorKey(width=width, height=height, max_steps=100), n=1000)
    doors = grids[..., 0] == DOOR
    assert (doors.sum(axis=(1, 2)) == 1).all(), f"{(doors.sum(axis=(1, 2)) == 0).sum()} no door"
    ours = doorkey_choices(grids, pos, dirs)
    ref = doorkey_choices(*minigrid_resets(RectDoorKey(width, height), n=1000))
    for name in ("door_row", "split", "agent_cell"):
        assert_same_support_and_chi2(f"DoorKey {width}x{height} {name}", ours[name], ref[name])


# --------------------------------------------------------------------------------- LavaGap


def lavagap_choices(grids, pos, dirs):
    n, w, h, _ = grids.shape
    check_border_and_goal(grids)
    assert (pos == (1, 1)).all() and (dirs == 0).all()
    lava = grids[..., 0] == LAVA
    assert (grids[lava] == (LAVA, RED, 0)).all()
    columns = lava.any(axis=2)  # (n, w)
    assert (columns.sum(axis=1) == 1).all(), "one lava column"
    gap_x = columns.argmax(axis=1)
    strip = lava[np.arange(n), gap_x, 1 : h - 1]  # (n, h - 2)
    assert (strip.sum(axis=1) == h - 3).all(), "one gap in the strip"
    gap_y = 1 + (~strip).argmax(axis=1)
    rest = grids.copy()
    rest[lava] = (EMPTY, 0, 0)
    interior = rest[:, 1 : w - 1, 1 : h - 1, 0]
    interior[:, w - 3, h - 3] = EMPTY  # the goal
    assert (interior == EMPTY).all()
    return {"gap_x": gap_x, "gap_y": gap_y, "gap": gap_x * h + gap_y}


@pytest.mark.parametrize("size", [pytest.param(5, marks=pytest.mark.slow), 7])
def test_lavagap_layout_distribution(size):
    env_id = f"MiniGrid-LavaGapS{size}-v0"
    ours = lavagap_choices(*jax_resets(jaxgrid.make(env_id), N_JAX))
    ref = lavagap_choices(*minigrid_resets(R.make_reference(env_id), N_MINIGRID))
    for name in ours:
        assert_same_support_and_chi2(f"{env_id} {name}", ours[name], ref[name])


# ----------------------------------------------------------------------------------- Empty


def empty_choices(grids, pos, dirs):
    n, w, h, _ = grids.shape
    check_border_and_goal(grids)
    assert (grids[:, 1 : w - 1, 1 : h - 1, 0] != EMPTY).sum() == n  # only the goal inside
    assert (grids[np.arange(n), pos[:, 0], pos[:, 1], 0] == EMPTY).all()
    return {"agent_cell": cell_id(pos, h), "agent_dir": dirs, "pose": cell_id(pos, h) * 4 + dirs}


@pytest.mark.parametrize("size", [5, pytest.param(6, marks=pytest.mark.slow)])
def test_empty_random_layout_distribution(size):
    env_id = f"MiniGrid-Empty-Random-{size}x{size}-v0"
    ours = empty_choices(*jax_resets(jaxgrid.make(env_id), N_JAX))
    ref = empty_choices(*minigrid_resets(R.make_reference(env_id), N_MINIGRID))
    for name in ours:
        assert_same_support_and_chi2(f"{env_id} {name}", ours[name], ref[name])


@pytest.mark.parametrize("size", [5, 6, 8, 16])
def test_empty_fixed_start_is_minigrids(size):
    env_id = f"MiniGrid-Empty-{size}x{size}-v0"
    grids, pos, dirs = jax_resets(jaxgrid.make(env_id), n=64)
    ref_grids, ref_pos, ref_dirs = minigrid_resets(R.make_reference(env_id), n=4)
    assert (ref_grids == ref_grids[0]).all() and (ref_pos == (1, 1)).all()
    assert (grids == ref_grids[0]).all()
    assert (pos == ref_pos[0]).all() and (dirs == ref_dirs[0]).all()
