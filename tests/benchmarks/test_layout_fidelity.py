"""benchmarks.layout_fidelity: its statistics pass a faithful generator and catch a wrong one."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks import layout_fidelity as LF
from jaxgrid.ascii import from_ascii


def test_a_faithful_id_passes_with_every_statistic():
    report = LF.fidelity("MiniGrid-DoorKey-5x5-v0", resets=300, alpha=1e-3)
    assert report["passed"], report
    names = set(report["p"])
    assert {"agent cell", "agent direction", "goal cell", "shortest path"} <= names
    assert {"cells wall", "cells door", "cells key", "count key c4 s0"} <= names


def test_a_different_start_distribution_fails():
    ours = LF.jaxgrid_layouts("MiniGrid-Empty-Random-6x6-v0", 300)
    ref = LF.minigrid_layouts("MiniGrid-Empty-6x6-v0", 300)
    p = LF.compare(ours, ref)
    assert p["agent cell"] < 1e-20 and p["agent direction"] < 1e-20
    assert p["goal cell"] == 1.0  # the goal is in the corner in both


def test_a_category_one_side_never_draws_fails():
    ours, ref = np.zeros(400, int), np.zeros(400, int)
    ours[:30] = 1  # 30 draws of a value MiniGrid never shows in 400
    assert LF.categorical_p(ours, ref) < 1e-10
    assert LF.categorical_p(ours[:200], np.concatenate([ours[:15], ref[:185]])) > 1e-3


def test_shortest_path_goes_around_walls_and_lava():
    level = from_ascii(
        """
        ##########
        ##>>V.G.##
        ##......##
        ##########
        """
    )
    grid = level.grid[None]
    assert LF.path_lengths(grid, np.array([[1, 1]]))[0] == 4  # down, right, right, up
    walled = grid.copy()
    walled[0, 1:4, 2] = walled[0, 0, 0]  # a wall row under the top row
    assert LF.path_lengths(walled, np.array([[1, 1]]))[0] == -1


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--ids", "MiniGrid-Nope-v0"], "not a native MiniGrid id"),
        (["--resets", "5"], "at least 20"),
        (["--alpha", "2"], "alpha"),
    ],
)
def test_bad_arguments_are_refused(argv, message, capsys):
    with pytest.raises(SystemExit):
        LF.main(argv)
    assert message in capsys.readouterr().err
