"""Reporting of the paper-reproduction experiments: the ``results.json`` contract, statistics
over seeds, the learning-curve figure, the Markdown table and the console summary.

matplotlib and ``scipy.stats`` are imported only inside the functions that need them (their
imports cost about a second each), and the figure goes through
:class:`matplotlib.figure.Figure` and the Agg canvas, never ``pyplot``, so no global backend or
figure state is touched.

Contents

- :data:`RESULTS_SCHEMA` and :func:`validate_results`: the ``results.json`` contract.
- :func:`t_quantile` and :func:`mean_ci`: Student-t confidence intervals over seeds.
- :func:`plot_curves`: violation % and mean reward against env steps, one line per mode with a
  95% bootstrap band of the interquartile mean over seeds (the paper's Figures 4 and 5).
- :func:`results_table`, :func:`write_report`, :func:`summarise`: Markdown table, atomic
  ``results.json`` + ``results.md``, and the end-of-run console summary.

Conventions for the optional extras that this module understands (all other extra keys are
allowed and passed through untouched):

- ``methods.<mode>.final_per_seed``: ``{"violation_rate": [S], "mean_reward": [S],
  "success_rate": [S]}`` (any subset). When present (and ``iqm`` is not) the table shows
  ``mean ± CI half-width``.
- ``methods.<mode>.iqm``: ``{metric: {"iqm", "lo", "hi", "per_seed"}}``
  (:func:`experiments.stats.summary`); the table shows ``IQM [lo, hi]``.
- ``methods.<mode>.final_unshielded``: the shield modes' policy evaluated without its shield.
- ``comparisons``: ``{name: {"p", "lo", "hi"}}`` probabilities of improvement.
- ``methods.<mode>.curve_per_seed``: ``{"step": [T], "violation_rate": [S][T],
  "mean_reward": [S][T], "success_rate": [S][T]}``, read by :func:`curves_from_results`.
- ``checker.transfer``: a metrics dict like ``checker.test`` (e.g. the 2Rooms checker on
  3Rooms-Key), or null.
"""

from __future__ import annotations

import io
import math
import numbers
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from agents.config import REWARD_MODES
from experiments.stats import bootstrap_ci
from jaxgrid.io import atomic_write, write_json

__all__ = [
    "CHECKER_METRICS",
    "CHECKER_SPLITS",
    "MODES",
    "MODE_COLORS",
    "MODE_LABELS",
    "RESULTS_SCHEMA",
    "ReportPaths",
    "curves_from_results",
    "mean_ci",
    "plot_curves",
    "plot_sweep",
    "results_table",
    "summarise",
    "t_quantile",
    "validate_results",
    "write_report",
]

# ----------------------------------------------------------------------------------------------
# Schema
# ----------------------------------------------------------------------------------------------

#: The reward/cost modes, in the display order of tables and figures.
MODES: tuple[str, ...] = REWARD_MODES

#: One fixed colour per mode, shared by every figure.
MODE_COLORS: dict[str, str] = {
    "checker": "#1f77b4",  # blue: the paper's method
    "shaped": "#2ca02c",  # green: ground-truth shaped baseline
    "none": "#d62728",  # red: unconstrained
    "lagrangian": "#9467bd",  # purple: PPO-Lagrangian on the checker's cost
    "shield": "#ff7f0e",  # orange: the checker blocks unsafe actions
    "shield_monitor": "#7f7f7f",  # grey: the ground-truth monitor blocks them (reference)
}

MODE_LABELS: dict[str, str] = {
    "checker": "checker-shaped",
    "shaped": "ground-truth shaped",
    "none": "unconstrained",
    "lagrangian": "PPO-Lagrangian",
    "shield": "checker shield",
    "shield_monitor": "monitor shield",
}

#: Metrics of the learned checker, all in [0, 1].
CHECKER_METRICS: tuple[str, ...] = ("accuracy", "precision", "recall", "f1", "auroc", "ece")
#: Checker evaluation splits shown in the table; ``test`` is required, the others may be null.
CHECKER_SPLITS: tuple[str, ...] = ("test", "heldout", "transfer")

_FINAL_KEYS = ("violation_rate", "mean_reward", "success_rate", "episodes")
_CURVE_KEYS = ("step", "violation_rate", "mean_reward", "success_rate")
_RATE_KEYS = frozenset({"violation_rate", "success_rate"})

#: Human-readable description of ``results.json``. ``"rate"`` = float in [0, 1]; ``"float"`` =
#: finite real; ``"int>=k"`` = integer >= k; ``"... | null"`` = may be null. Extra keys are
#: allowed everywhere.
RESULTS_SCHEMA: dict[str, Any] = {
    "experiment": "str (non-empty)",
    "config": "object (free-form run configuration)",
    "checker": {
        "test": {m: "rate" for m in CHECKER_METRICS},
        "heldout": "same as test | null (key required; null when not measured)",
        "transfer": "optional: same as test | null",
        "shield": "optional: the shield's own checker: {test: same as test, guided: rate, "
        "auroc_by}",
    },
    "methods": {
        "<mode in checker|shaped|none|lagrangian|shield|shield_monitor> (at least one)": {
            "final": {
                "violation_rate": "rate",
                "mean_reward": "float",
                "success_rate": "rate",
                "episodes": "int>=1",
            },
            "training_violations": "int>=0",
            "curve": [
                {
                    "step": "int>=0 (non-decreasing along the list)",
                    "violation_rate": "rate",
                    "mean_reward": "float",
                    "success_rate": "rate",
                }
            ],
            "seeds": "int>=1",
            "final_per_seed": "optional: {violation_rate|mean_reward|success_rate: [seeds]}",
        }
    },
    "timing": {"total_s": "float>=0"},
    "code": "optional: [{sha256, versions, git, first_used}] every code that wrote the run",
}


def _is_int(x: Any) -> bool:
    if isinstance(x, bool | np.bool_):
        return False
    return isinstance(x, numbers.Integral)


def _is_real(x: Any) -> bool:
    return (
        isinstance(x, numbers.Real)
        and not isinstance(x, bool | np.bool_)
        and math.isfinite(float(x))
    )


def _fmt(x: Any) -> str:
    s = repr(x)
    return s if len(s) <= 60 else s[:57] + "..."


def _require_mapping(d: Any, path: str) -> Mapping:
    if not isinstance(d, Mapping):
        raise ValueError(f"{path}: expected an object, got {type(d).__name__} {_fmt(d)}")
    return d


def _get(d: Mapping, key: str, path: str) -> Any:
    if key not in d:
        raise ValueError(f"{path + '.' if path else ''}{key}: missing required key")
    return d[key]


def _check_rate(x: Any, path: str) -> None:
    if not _is_real(x) or not 0.0 <= float(x) <= 1.0:
        raise ValueError(f"{path}: expected a float in [0, 1], got {_fmt(x)}")


def _check_real(x: Any, path: str, minimum: float | None = None) -> None:
    if not _is_real(x):
        raise ValueError(f"{path}: expected a finite float, got {_fmt(x)}")
    if minimum is not None and float(x) < minimum:
        raise ValueError(f"{path}: expected a float >= {minimum}, got {_fmt(x)}")


def _check_int(x: Any, path: str, minimum: int) -> None:
    if not _is_int(x) or int(x) < minimum:
        raise ValueError(f"{path}: expected an int >= {minimum}, got {_fmt(x)}")


def _check_metrics(m: Any, path: str) -> None:
    m = _require_mapping(m, path)
    for k in CHECKER_METRICS:
        _check_rate(_get(m, k, path), f"{path}.{k}")


def validate_results(results: dict) -> None:
    """Check ``results`` against :data:`RESULTS_SCHEMA`; return None or raise ``ValueError``.

    The message starts with the dotted key path of the first offending value, e.g.
    ``methods.checker.final.violation_rate: expected a float in [0, 1], got 1.3``. Numpy
    scalars are accepted (validation may run before JSON serialisation); NaN/inf are not.
    """
    _require_mapping(results, "<results>")
    exp = _get(results, "experiment", "")
    if not isinstance(exp, str) or not exp:
        raise ValueError(f"experiment: expected a non-empty str, got {_fmt(exp)}")
    _require_mapping(_get(results, "config", ""), "config")

    chk = _require_mapping(_get(results, "checker", ""), "checker")
    _check_metrics(_get(chk, "test", "checker"), "checker.test")
    if _get(chk, "heldout", "checker") is not None:
        _check_metrics(chk["heldout"], "checker.heldout")
    if chk.get("transfer") is not None:
        _check_metrics(chk["transfer"], "checker.transfer")
    if chk.get("shield") is not None:
        shield = _require_mapping(chk["shield"], "checker.shield")
        _check_metrics(_get(shield, "test", "checker.shield"), "checker.shield.test")

    methods = _require_mapping(_get(results, "methods", ""), "methods")
    if not methods:
        raise ValueError("methods: expected at least one mode, got an empty object")
    for mode, entry in methods.items():
        p = f"methods.{mode}"
        if mode not in MODES:
            raise ValueError(f"{p}: unknown mode {mode!r}; expected one of {', '.join(MODES)}")
        entry = _require_mapping(entry, p)

        final = _require_mapping(_get(entry, "final", p), f"{p}.final")
        for k in _FINAL_KEYS:
            v = _get(final, k, f"{p}.final")
            if k == "episodes":
                _check_int(v, f"{p}.final.episodes", 1)
            elif k in _RATE_KEYS:
                _check_rate(v, f"{p}.final.{k}")
            else:
                _check_real(v, f"{p}.final.{k}")

        _check_int(_get(entry, "training_violations", p), f"{p}.training_violations", 0)
        _check_int(_get(entry, "seeds", p), f"{p}.seeds", 1)
        seeds = int(entry["seeds"])

        curve = _get(entry, "curve", p)
        if not isinstance(curve, Sequence) or isinstance(curve, str | bytes):
            raise ValueError(f"{p}.curve: expected a list of points, got {_fmt(curve)}")
        prev_step = -1
        for i, point in enumerate(curve):
            pp = f"{p}.curve[{i}]"
            point = _require_mapping(point, pp)
            for k in _CURVE_KEYS:
                v = _get(point, k, pp)
                if k == "step":
                    _check_int(v, f"{pp}.step", 0)
                    if int(v) < prev_step:
                        raise ValueError(
                            f"{pp}.step: steps must be non-decreasing, got {int(v)} after "
                            f"{prev_step}"
                        )
                    prev_step = int(v)
                elif k in _RATE_KEYS:
                    _check_rate(v, f"{pp}.{k}")
                else:
                    _check_real(v, f"{pp}.{k}")

        if entry.get("final_per_seed") is not None:
            pp = f"{p}.final_per_seed"
            fps = _require_mapping(entry["final_per_seed"], pp)
            for k, vals in fps.items():
                if k not in _RATE_KEYS | {"mean_reward"}:
                    continue  # extra per-seed arrays are allowed
                if not isinstance(vals, Sequence | np.ndarray) or isinstance(vals, str):
                    raise ValueError(f"{pp}.{k}: expected a list, got {_fmt(vals)}")
                if len(vals) != seeds:
                    raise ValueError(
                        f"{pp}.{k}: expected {seeds} values (one per seed), got {len(vals)}"
                    )
                for j, v in enumerate(vals):
                    (_check_rate if k in _RATE_KEYS else _check_real)(v, f"{pp}.{k}[{j}]")

    timing = _require_mapping(_get(results, "timing", ""), "timing")
    _check_real(_get(timing, "total_s", "timing"), "timing.total_s", minimum=0.0)


# ----------------------------------------------------------------------------------------------
# Statistics
# ----------------------------------------------------------------------------------------------


def t_quantile(p: float, df: float) -> float:
    """Quantile (inverse CDF) of Student's t distribution: ``P(T <= t_quantile(p, df)) = p``.

    Any real ``df > 0`` works, and ``df = inf`` gives the normal quantile. E.g.
    ``t_quantile(0.975, 4)`` = 2.7764, ``t_quantile(0.975, inf)`` = 1.9600. Bad ``p`` or ``df``
    raise ``ValueError`` naming the argument.
    """
    if not 0.0 < p < 1.0:
        raise ValueError(f"p: expected a probability in (0, 1), got {p!r}")
    if not df > 0:
        raise ValueError(f"df: expected df > 0, got {df!r}")
    from scipy import stats

    return float(stats.t.ppf(p, df))


def mean_ci(values: Any, axis: int = 0, confidence: float = 0.95) -> tuple[Any, Any, Any]:
    """Mean and Student-t confidence interval of ``values`` along ``axis`` (e.g. over seeds).

    Returns ``(mean, lo, hi)`` with ``lo/hi = mean -/+ t_{(1+c)/2, n-1} * s / sqrt(n)``, ``s`` the
    sample standard deviation (ddof=1). With a single value along ``axis`` the interval is
    degenerate: ``lo = hi = mean``. Results are Python floats for a 1-D input, arrays otherwise.
    """
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: expected a value in (0, 1), got {confidence!r}")
    x = np.asarray(values, dtype=np.float64)
    if x.ndim == 0:
        raise ValueError("values: expected at least one dimension (the samples)")
    n = x.shape[axis]
    if n == 0:
        raise ValueError(f"values: no samples along axis {axis}")
    mean = x.mean(axis=axis)
    if n == 1:
        half = np.zeros_like(mean)
    else:
        sem = x.std(axis=axis, ddof=1) / math.sqrt(n)
        half = t_quantile(0.5 + confidence / 2.0, n - 1) * sem
    lo, hi = mean - half, mean + half
    if np.ndim(mean) == 0:
        return float(mean), float(lo), float(hi)
    return mean, lo, hi


# ----------------------------------------------------------------------------------------------
# Figures
# ----------------------------------------------------------------------------------------------


def _ordered_modes(modes: Any) -> list[str]:
    modes = list(modes)
    return [m for m in MODES if m in modes] + [m for m in modes if m not in MODES]


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
    for mode in _ordered_modes(per_seed_curves):
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
            if key in _RATE_KEYS:  # an interval never leaves the metric's range
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


def plot_sweep(summary: Mapping, path: str | os.PathLike, title: str | None = None,
               *, dpi: int = 120) -> Path:
    """A two-panel PNG of a sweep (:func:`experiments.phases.write_sweep`'s summary): final
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
    for mode in _ordered_modes({r["mode"]: None for r in rows}):
        mine = sorted((r for r in rows if r["mode"] == mode), key=lambda r: r[name])
        x = np.array([r[name] for r in mine], dtype=np.float64)
        for ax, key in zip(axes, ("violation_rate", "success_rate"), strict=True):
            mid, lo, hi = (np.clip(100.0 * np.array([r[key][k] for r in mine]), 0.0, 100.0)
                           for k in ("iqm", "lo", "hi"))  # fmt: skip
            ax.errorbar(x, mid, yerr=[mid - lo, hi - mid], marker="o", capsize=3,
                        color=MODE_COLORS.get(mode), label=MODE_LABELS.get(mode, mode))
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


# ----------------------------------------------------------------------------------------------
# Tables, files, console
# ----------------------------------------------------------------------------------------------


def _cell(entry: Mapping, key: str, scale: float, digits: int, final: str = "final") -> str:
    """``IQM [lo, hi]`` (95% bootstrap) from the entry's ``iqm`` summaries when present, else
    ``mean ± t half-width`` from ``final_per_seed`` (>= 2 seeds), else the pooled final."""
    name = key if final == "final" else f"unshielded_{key}"
    summary = (entry.get("iqm") or {}).get(name)
    if summary is not None:
        point, lo, hi = (summary[k] * scale for k in ("iqm", "lo", "hi"))
        return f"{point:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"
    per_seed = (entry.get(f"{final}_per_seed") or {}).get(key)
    if per_seed is not None and len(per_seed) >= 2:
        mean, lo, hi = mean_ci(np.asarray(per_seed, dtype=np.float64) * scale)
        return f"{mean:.{digits}f} ± {(hi - lo) / 2:.{digits}f}"
    return f"{float(entry[final][key]) * scale:.{digits}f}"


def _count(entry: Mapping, key: str) -> str:
    summary = (entry.get("iqm") or {}).get(key)
    if summary is not None:
        return f"{summary['iqm']:.0f} [{summary['lo']:.0f}, {summary['hi']:.0f}]"
    return str(entry[key]) if key in entry else "n/a"


def results_table(results: Mapping) -> str:
    """Markdown tables: one row per mode (shield modes twice: as deployed, and the policy
    without its shield), the comparisons, then the checker metrics per split.

    Method columns: final violation %, mean reward, success % and training violations (all,
    and in the first 20% of training): the interquartile mean over seeds with its 95%
    stratified-bootstrap interval where ``iqm`` summaries exist, else the mean; seeds, final
    evaluation episodes. Checker rows: test, heldout, transfer (``n/a`` when null).
    """
    lines = [
        "| Method | Final violation % | Mean reward | Success % | Training violations "
        "| ... in the first 20% | Seeds | Eval episodes |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    methods = results["methods"]
    for mode in _ordered_modes(methods):
        e = methods[mode]
        finals = [("final", "")] + ([("final_unshielded", ", shield off")]
                                    if "final_unshielded" in e else [])  # fmt: skip
        for final, note in finals:
            lines.append(
                f"| {mode} ({MODE_LABELS.get(mode, mode)}{note}) "
                f"| {_cell(e, 'violation_rate', 100.0, 1, final)} "
                f"| {_cell(e, 'mean_reward', 1.0, 3, final)} "
                f"| {_cell(e, 'success_rate', 100.0, 1, final)} "
                f"| {_count(e, 'training_violations')} "
                f"| {_count(e, 'training_violations_first20')} "
                f"| {int(e['seeds'])} "
                f"| {int(e[final]['episodes'])} |"
            )
    lines += [
        "",
        "Interquartile mean over seeds [95% stratified-bootstrap interval]; training "
        "violations per seed, counted from the first update.",
    ]
    comparisons = results.get("comparisons") or {}
    if comparisons:
        lines += ["", "| Comparison | P | 95% interval |", "|---|---:|---:|"]
        for name, c in comparisons.items():
            x, key = name.split("_beats_shaped_")
            what = "in the first 20% of training" if key.endswith("first20") else "in training"
            lines.append(f"| P({x} has fewer violations than shaped {what}) "
                         f"| {c['p']:.2f} | [{c['lo']:.2f}, {c['hi']:.2f}] |")  # fmt: skip
    lines += [
        "",
        "| Checker split | Accuracy | Precision | Recall | F1 | AUROC | ECE |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    chk = results.get("checker") or {}
    row = lambda name, m: f"| {name} |" + "".join(  # noqa: E731
        f" {float(m[k]):.3f} |" for k in CHECKER_METRICS
    )
    for split in CHECKER_SPLITS:
        m = chk.get(split)
        if m is None:
            if split == "transfer":
                continue  # only shown by experiments that measure transfer
            lines.append(f"| {split} |" + " n/a |" * len(CHECKER_METRICS))
            continue
        lines.append(row(split, m))
    shield = chk.get("shield")
    if shield:  # the shield's own checker, on its own streams' test split
        lines.append(row(f"test, shield's checker (guided {float(shield['guided']):g})",
                         shield["test"]))  # fmt: skip
    by = chk.get("auroc_by")
    if by:  # a memory checker: how well it ranks each constraint type, and counts
        rows = [("memory checker", by)]
        if shield and shield.get("auroc_by"):
            rows.append(("shield's checker", shield["auroc_by"]))
        lines += ["", "| Checker AUROC on test | " + " | ".join(by) + " |",
                  "|---|" + "---:|" * len(by)]  # fmt: skip
        lines += [f"| {name} | " + " | ".join("n/a" if aurocs.get(k) is None else
                                              f"{aurocs[k]:.3f}" for k in by) + " |"
                  for name, aurocs in rows]  # fmt: skip
    return "\n".join(lines) + "\n"


class ReportPaths(NamedTuple):
    """Files written by :func:`write_report`."""

    json: Path
    md: Path


def _format_duration(seconds: float) -> str:
    s = int(round(seconds))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h {m:02d}m {s:02d}s" if h else f"{m}m {s:02d}s"


def _baseline_note(timing: Mapping) -> str:
    """`` on a machine where ...``: the baseline learner's figure, when it was measured."""
    base = timing.get("machine_baseline")
    if not base:
        return ""
    return (
        f", on a machine where the PureJaxRL-style PPO baseline (`python -m "
        f"benchmarks.purejaxrl_ppo --env {base['env']}`) runs at {float(base['sps']):,.0f} "
        f"steps/s ({base['device']})"
    )


def _code_note(entries: list) -> str:
    """Which code made the results (``results["code"]``, :mod:`experiments.provenance`)."""
    if not entries:
        return ""
    last = entries[-1]
    git = f", git {last['git']}" if last.get("git") else ""
    jax_version = last["versions"].get("jax")
    note = f"\nCode: sources sha256 {last['sha256'][:12]}{git}, jax {jax_version}.\n"
    if len(entries) > 1:
        note += (
            f"\n**Warning: {len(entries)} versions of the code wrote into this directory** (a "
            "resume after a change; `code.json`): phases made by an earlier one were kept, so "
            "a fresh run of the same command may give other figures.\n"
        )
    return note


def _smoke_note(results: Mapping) -> str:
    """A warning atop a ``--quick`` run's report: its sizes test the outputs, not the agents."""
    if not (results.get("config") or {}).get("quick"):
        return ""
    return ("**A `--quick` smoke test: these numbers mean nothing** (a few thousand steps, "
            "two seeds); run without `--quick` for results.\n\n")  # fmt: skip


def write_report(results: dict, out_dir: str | os.PathLike) -> ReportPaths:
    """Validate ``results`` then atomically write ``results.json`` and ``results.md``.

    Raises ``ValueError`` (see :func:`validate_results`) before touching the filesystem when
    ``results`` is invalid. Numpy values are converted, NaN/inf extras become null
    (:func:`jaxgrid.io.write_json`). Each file is written atomically, so a reader never sees a
    partial file. Returns ``ReportPaths(json, md)``.
    """
    validate_results(results)
    out = Path(out_dir)
    md = (
        f"# Results: {results['experiment']}\n\n"
        + _smoke_note(results)
        + results_table(results)
        + f"\nTotal wall time: {_format_duration(float(results['timing']['total_s']))}"
        + _baseline_note(results["timing"])
        + ".\n"
        + _code_note(results.get("code") or [])
    )
    json_path, md_path = out / "results.json", out / "results.md"
    write_json(json_path, results)
    atomic_write(md_path, md)
    return ReportPaths(json_path, md_path)


def summarise(results: Mapping) -> str:
    """Short multi-line console summary: one line per mode, the checker AUROC and wall time."""
    quick = (results.get("config") or {}).get("quick")
    lines = [f"{results.get('experiment', '?')}" + (" (--quick: these numbers mean nothing)"
                                                    if quick else "") + ":"]  # fmt: skip
    methods = results["methods"]
    width = max(len(m) for m in methods)
    for mode in _ordered_modes(methods):
        e = methods[mode]
        lines.append(
            f"  {mode:<{width}}  violations {_cell(e, 'violation_rate', 100.0, 1)}%"
            f"  reward {_cell(e, 'mean_reward', 1.0, 3)}"
            f"  success {_cell(e, 'success_rate', 100.0, 1)}%"
            f"  training violations {_count(e, 'training_violations')}"
            f"  ({int(e['seeds'])} seeds, {int(e['final']['episodes'])} episodes)"
        )
    chk = results.get("checker") or {}
    parts = [
        f"{split} {float(chk[split]['auroc']):.3f}"
        for split in CHECKER_SPLITS
        if chk.get(split) is not None
    ]
    if chk.get("shield") is not None:
        parts.append(f"shield's checker {float(chk['shield']['test']['auroc']):.3f}")
    lines.append("  checker AUROC: " + (", ".join(parts) if parts else "n/a"))
    total = (results.get("timing") or {}).get("total_s")
    if total is not None:
        lines.append(f"  total time: {_format_duration(float(total))}")
    return "\n".join(lines)
