"""The figures of a report: learning curves and a sweep's summary, as PNG files.

- :func:`plot_curves`: violation % and mean reward against env steps, one line per mode with a
  95% bootstrap band of the interquartile mean over seeds (the paper's Figures 4 and 5);
  :func:`curves_from_results` gives its input from a ``results.json`` object.
- :func:`plot_sweep`: final violation % and success % against a swept value.
- :func:`plot_benchmark_level`: one benchmark level, success against training violations,
  a point per method with its intervals.

matplotlib is imported only inside the functions that draw (its import costs about a second),
and a figure goes through :class:`matplotlib.figure.Figure` and the Agg canvas, never
``pyplot``, so no global backend or figure state is touched.
"""

from __future__ import annotations

import io
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from experiments.report.schema import MODE_LABELS, RATE_KEYS, ordered_modes
from experiments.stats import bootstrap_ci
from jaxgrid.io import atomic_write

__all__ = ["MODE_COLORS", "curves_from_results", "plot_benchmark_level", "plot_curves",
           "plot_sweep"]  # fmt: skip

#: One fixed colour per mode, shared by every figure.
MODE_COLORS: dict[str, str] = {
    "checker": "#1f77b4",  # blue: the paper's method
    "shaped": "#2ca02c",  # green: ground-truth shaped baseline
    "none": "#d62728",  # red: unconstrained
    "lagrangian": "#9467bd",  # purple: PPO-Lagrangian on the checker's cost
    "shield": "#ff7f0e",  # orange: the checker blocks unsafe actions
    "shield_monitor": "#7f7f7f",  # grey: the ground-truth monitor blocks them (reference)
}


def _as_seed_matrix(a: Any, steps: int, path: str) -> np.ndarray:
    x = np.asarray(a, dtype=np.float64)
    if x.ndim == 1:
        x = x[None, :]
    if x.ndim != 2 or x.shape[1] != steps:
        raise ValueError(f"{path}: expected shape (seeds, {steps}), got {np.shape(a)}")
    return x


def curves_from_results(results: Mapping) -> dict[str, dict[str, np.ndarray]]:
    """Per-seed curves for :func:`plot_curves` from a results dict.

    Uses ``methods.<mode>.curve_per_seed`` when present, otherwise the mean ``curve`` as a single
    "seed" (then the plot has no CI band).
    """
    out: dict[str, dict[str, np.ndarray]] = {}
    for mode, entry in results["methods"].items():
        per_seed = entry.get("curve_per_seed")
        if per_seed is not None:
            out[mode] = {k: np.asarray(v, dtype=np.float64) for k, v in per_seed.items()}
            continue
        curve = entry["curve"]
        out[mode] = {"step": np.asarray([pt["step"] for pt in curve], dtype=np.float64)}
        for k in ("violation_rate", "mean_reward", "success_rate"):
            out[mode][k] = np.asarray([[pt[k] for pt in curve]], dtype=np.float64)
    return out


def plot_curves(
    per_seed_curves: Mapping[str, Mapping[str, Any]],
    path: str | os.PathLike,
    title: str | None = None,
    *,
    confidence: float = 0.95,
    dpi: int = 120,
    figsize: tuple[float, float] = (11.0, 4.2),
) -> Path:
    """Write a two-panel PNG: violation % and mean episode reward against env steps.

    ``per_seed_curves`` maps a mode to ``{"step": (T,), "violation_rate": (S, T),
    "mean_reward": (S, T)}`` (``success_rate`` optional and not drawn; a (T,) array counts as one
    seed). Each mode is a line (interquartile mean over seeds) with a shaded ``confidence``
    bootstrap band (:mod:`experiments.stats`; rates clipped to [0, 100]),
    in the fixed :data:`MODE_COLORS`. The image is ``figsize * dpi`` pixels (1320 x 504 by
    default). Written atomically; returns the path.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.ticker import EngFormatter

    if not per_seed_curves:
        raise ValueError("per_seed_curves: expected at least one mode")
    path = Path(path)
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    ax_v, ax_r = fig.subplots(1, 2)
    extra_colors = iter(["#ff7f0e", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf"])
    for mode in ordered_modes(per_seed_curves):
        c = per_seed_curves[mode]
        if "step" not in c:
            raise ValueError(f"{mode}.step: missing")
        step = np.asarray(c["step"], dtype=np.float64)
        if step.ndim != 1:
            raise ValueError(f"{mode}.step: expected shape (T,), got {step.shape}")
        color = MODE_COLORS.get(mode) or next(extra_colors, "#000000")
        for ax, key, scale in ((ax_v, "violation_rate", 100.0), (ax_r, "mean_reward", 1.0)):
            if key not in c:
                raise ValueError(f"{mode}.{key}: missing")
            y = _as_seed_matrix(c[key], step.shape[0], f"{mode}.{key}") * scale
            mid, lo, hi = np.array([bootstrap_ci(col, confidence=confidence) for col in y.T]).T
            if key in RATE_KEYS:  # an interval never leaves the metric's range
                lo, hi = np.clip(lo, 0.0, 100.0), np.clip(hi, 0.0, 100.0)
            seeds = y.shape[0]
            label = f"{MODE_LABELS.get(mode, mode)} (n={seeds})"
            ax.plot(step, mid, color=color, lw=1.8, label=label)
            if seeds > 1:
                ax.fill_between(step, lo, hi, color=color, alpha=0.2, lw=0)
    pct = int(round(confidence * 100))
    ax_v.set_ylabel("episodes with a violation (%)")
    ax_v.set_title("Constraint violations")
    ax_v.set_ylim(bottom=0)
    ax_r.set_ylabel("mean episode reward (env reward)")
    ax_r.set_title("Task reward")
    for ax in (ax_v, ax_r):
        ax.set_xlabel("environment steps")
        ax.xaxis.set_major_formatter(EngFormatter(sep=""))
        ax.grid(True, alpha=0.3)
    ax_r.legend(loc="best", fontsize=8, title=f"IQM, {pct}% bootstrap CI over seeds",
                title_fontsize=8)  # fmt: skip
    if title:
        fig.suptitle(title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    atomic_write(path, buf.getvalue())
    return path


def plot_sweep(
    summary: Mapping, path: str | os.PathLike, title: str | None = None, *, dpi: int = 120
) -> Path:
    """A two-panel PNG of a sweep (:func:`experiments.assembly.write_sweep`'s summary): final
    violation % and success % against the swept value, one line per mode (interquartile
    mean over seeds, 95% bootstrap interval as error bars, clipped to [0, 100])."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    name, rows = summary["sweep"]["name"], summary["rows"]
    if not rows:
        raise ValueError("summary.rows: expected at least one (value, mode) row")
    fig = Figure(figsize=(11.0, 4.2), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    positive = all(r[name] > 0 for r in rows)
    for mode in ordered_modes({r["mode"]: None for r in rows}):
        mine = sorted((r for r in rows if r["mode"] == mode), key=lambda r: r[name])
        x = np.array([r[name] for r in mine], dtype=np.float64)
        for ax, key in zip(axes, ("violation_rate", "success_rate"), strict=True):
            mid, lo, hi = (np.clip(100.0 * np.array([r[key][k] for r in mine]), 0.0, 100.0)
                           for k in ("iqm", "lo", "hi"))  # fmt: skip
            ax.errorbar(
                x,
                mid,
                yerr=[mid - lo, hi - mid],
                marker="o",
                capsize=3,
                color=MODE_COLORS.get(mode),
                label=MODE_LABELS.get(mode, mode),
            )
    for ax, label in zip(axes, ("final violation %", "final success %"), strict=True):
        ax.set_xlabel(name)
        ax.set_ylabel(label)
        ax.set_ylim(-2, 102)
        ax.grid(True, alpha=0.3)
        if positive and max(r[name] for r in rows) / min(r[name] for r in rows) >= 10:
            ax.set_xscale("log")
    axes[1].legend(loc="best", fontsize=8, title="IQM, 95% bootstrap CI", title_fontsize=8)
    if title:
        fig.suptitle(title)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    atomic_write(Path(path), buf.getvalue())
    return Path(path)


def plot_benchmark_level(
    level: Mapping, name: str, path: str | os.PathLike, *, dpi: int = 120
) -> Path:
    """A PNG of one level of the benchmark's summary (``OUT/benchmark.json``): final success %
    against violations during training, a point per method at its interquartile means over
    seeds, with both 95% bootstrap intervals as error bars; a method whose results lack one
    of the two is left out."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 4.6), dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    for mode in ordered_modes(level["methods"]):
        figures = level["methods"][mode]
        if "training_violations" not in figures or "success_rate" not in figures:
            continue
        v, s = figures["training_violations"], figures["success_rate"]
        ax.errorbar(v["iqm"], 100.0 * s["iqm"],
                    xerr=[[v["iqm"] - v["lo"]], [v["hi"] - v["iqm"]]],
                    yerr=[[100.0 * (s["iqm"] - s["lo"])], [100.0 * (s["hi"] - s["iqm"])]],
                    marker="o", capsize=3, linestyle="none", color=MODE_COLORS.get(mode),
                    label=MODE_LABELS.get(mode, mode))  # fmt: skip
    ax.set_xlabel("violations during training (per seed)")
    ax.set_ylabel("final success %")
    ax.set_ylim(-2, 102)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8, title="IQM, 95% bootstrap CI", title_fontsize=8)
    ax.set_title(f"{name} ({level['env_id']})")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    atomic_write(Path(path), buf.getvalue())
    return Path(path)
