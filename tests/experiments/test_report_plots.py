"""experiments.report.plots: the learning-curve figure and its input from results."""

from __future__ import annotations

import numpy as np
import pytest

from agents.config import PAPER_MODES as MODES  # the fixture's modes
from experiments.report import curves_from_results, plot_curves


def _curves(seeds=3, steps=12):
    rng = np.random.default_rng(2)
    t = np.linspace(0, 1e6, steps)
    out = {}
    for i, mode in enumerate(MODES):
        base = np.exp(-t / 3e5) * (0.1 + 0.2 * i)
        out[mode] = {
            "step": t,
            "violation_rate": np.clip(base + 0.02 * rng.standard_normal((seeds, steps)), 0, 1),
            "mean_reward": 1 - np.exp(-t / 2e5) + 0.05 * rng.standard_normal((seeds, steps)),
        }
    out["none"]["success_rate"] = np.ones((seeds, steps))
    return out


def test_plot_curves_writes_png(tmp_path):
    import imageio.v3 as iio

    path = plot_curves(_curves(), tmp_path / "sub" / "curves.png", title="TwoRooms")
    assert path.exists() and path.stat().st_size > 10_000
    img = iio.imread(path)
    assert img.shape[:2] == (504, 1320)  # figsize (11, 4.2) at 120 dpi
    # not a blank canvas: several distinct colours drawn
    assert len(np.unique(img.reshape(-1, img.shape[-1]), axis=0)) > 50
    assert not list(tmp_path.glob("sub/*.tmp"))


def test_plot_curves_single_seed_and_1d(tmp_path):
    import matplotlib.image

    c = {"checker": {"step": [0, 1, 2], "violation_rate": [0.5, 0.2, 0.1],
                     "mean_reward": [0.0, 0.4, 0.8]}}  # fmt: skip
    path = plot_curves(c, tmp_path / "one.png", dpi=50, figsize=(6, 3))
    assert matplotlib.image.imread(path).shape[:2] == (150, 300)


def test_plot_curves_rejects_bad_shape(tmp_path):
    c = _curves()
    c["shaped"]["mean_reward"] = c["shaped"]["mean_reward"][:, :-1]
    with pytest.raises(ValueError, match="shaped.mean_reward"):
        plot_curves(c, tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_curves_from_results(good, tmp_path):
    c = curves_from_results(good)
    assert set(c) == set(MODES)
    assert c["checker"]["violation_rate"].shape == (1, 3)
    good["methods"]["none"]["curve_per_seed"] = _curves()["none"]
    c = curves_from_results(good)
    assert c["none"]["violation_rate"].shape == (3, 12)
