"""Playground, generated natively, against MiniGrid 3.2.0.

* Layouts: vmapped jaxgrid resets and MiniGrid resets (one seeded RNG stream) are read back
  into the generator's random choices by one function for both sides: each wall's door cell
  and colour, the walls (MiniGrid's exactly), the objects' (type, colour) pairs, how many of
  each type, the agent's pose, and per-cell occupancy by doors and by objects; each marginal
  compared with a two-sample chi-square test at ``ALPHA`` (``helpers.layout_stats``).
* Steps: natively generated states copied into MiniGrid step like MiniGrid, every field at
  every step (``test_differential.py`` runs 200 seeds with ``-m slow``).
* The empty mission, refused sizes (registry defaults: ``test_differential.py``).
"""

from __future__ import annotations

import collections

import jax
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.layout_stats import compare_all, jax_resets, minigrid_resets
from helpers.xla import CHEAP

import jaxgrid
from jaxgrid.constants import BALL, BOX, CLOSED, DOOR, EMPTY, KEY, WALL
from jaxgrid.levels import Playground

ENV_ID = "MiniGrid-Playground-v0"


def choices(grids, pos, dirs):
    """Check Playground layouts; return their random choices."""
    env = jaxgrid.make(ENV_ID)
    vertical, horizontal = env.doors()
    walls = np.asarray(env.layout())[..., 0] == WALL
    out = collections.defaultdict(list)
    for grid, p, d in zip(grids, pos, dirs, strict=True):
        kind = grid[..., 0]
        is_door = kind == DOOR
        assert ((kind == WALL) == (walls & ~is_door)).all(), "walls differ from MiniGrid's"
        assert (grid[is_door][:, 2] == CLOSED).all() and is_door.sum() == 12
        for n, (x, low, high) in enumerate(vertical):
            (y,) = np.nonzero(is_door[x, low:high])[0] + low
            out[f"door{n}"].append(y * 8 + grid[x, y, 1])
        for n, (y, low, high) in enumerate(horizontal, start=len(vertical)):
            (x,) = np.nonzero(is_door[low:high, y])[0] + low
            out[f"door{n}"].append(x * 8 + grid[x, y, 1])
        objects = np.isin(kind, [KEY, BALL, BOX])
        assert objects.sum() == 12 and kind[tuple(p)] == EMPTY
        for k in (KEY, BALL, BOX):
            out[f"count{k}"].append((kind == k).sum())
        pairs = kind[objects] * 8 + grid[objects][:, 1]
        out["first_pair"].append(pairs[0])  # the object first in grid order
        out["distinct_pairs"].append(len(set(pairs.tolist())))
        out["agent"].append(p[0] * 19 + p[1])
        out["dir"].append(d)
    return {k: np.array(v) for k, v in out.items()}


def test_layouts_are_drawn_as_minigrid_draws_them():
    env = jaxgrid.make(ENV_ID)
    n = 1000
    ours = jax_resets(env, 2 * n)
    ref = minigrid_resets(R.make_reference(ENV_ID), n)
    a, b = choices(*ours), choices(*ref)
    a["cells:objects"] = np.isin(ours[0][..., 0], [KEY, BALL, BOX])
    b["cells:objects"] = np.isin(ref[0][..., 0], [KEY, BALL, BOX])
    compare_all(ENV_ID, a, b)


def test_native_states_step_like_minigrid():
    env = jaxgrid.make(ENV_ID)
    states, _ = jax.jit(jax.vmap(env.reset), compiler_options=CHEAP)(
        jax.random.split(jax.random.PRNGKey(5), 8)
    )
    actions = R.draw_actions(5, 8, env.max_steps)
    for b in range(8):
        state = jax.tree.map(lambda x, b=b: x[b], states)
        R.check_steps(env, state, actions[b], f"{ENV_ID} seed {b}")


def test_the_mission_is_empty_as_minigrids():
    mg = R.make_reference(ENV_ID)
    mg.reset(seed=0)
    env = jaxgrid.make(ENV_ID)
    state, _ = env.reset(jax.random.PRNGKey(0))
    assert env.mission_text(state) == mg.mission == ""


def test_impossible_sizes_are_refused():
    with pytest.raises(ValueError, match="width"):
        Playground(width=9, height=19, max_steps=10)
