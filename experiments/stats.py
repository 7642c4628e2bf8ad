"""Statistics over seeds as reviewers of deep-RL results ask for them (Agarwal et al., 2021).

- :func:`iqm`: the interquartile mean, the mean of the middle 50% of the runs (robust to one
  outlying seed, less noisy than the median).
- :func:`bootstrap_ci`: a percentile bootstrap interval of any such statistic, resampling
  runs with replacement within each task (*stratified*: with several tasks, each keeps its
  number of runs).
- :func:`probability_of_improvement`: ``P(X < Y)`` for a lower-is-better metric of two
  methods, counting ties as one half, with its bootstrap interval.
- :func:`mean_ci` and :func:`t_quantile`: the mean and its Student-t confidence interval, the
  report's fallback where a method has per-seed values but no IQM summary.

Everything is NumPy (and scipy's trimmed mean and t quantiles), with a fixed generator seed,
so a report is the same on every rerun.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

CONFIDENCE = 0.95
RESAMPLES = 2000
SEED = 0


def _runs(values, name: str = "values") -> np.ndarray:
    """(tasks, runs) float64 from a (runs,) or (tasks, runs) array of finite values."""
    x = np.asarray(values, dtype=np.float64)
    x = x[None] if x.ndim == 1 else x
    if x.ndim != 2 or x.shape[1] == 0:
        raise ValueError(
            f"{name}: expected (runs,) or (tasks, runs) values, got shape {np.shape(values)}"
        )
    if not np.isfinite(x).all():
        raise ValueError(f"{name}: expected finite values, got {values!r}")
    return x


def iqm(values) -> float:
    """Interquartile mean of ``values`` (all tasks' runs pooled): the mean after trimming a
    quarter of the runs (rounded down) from each end, as rliable computes it
    (``scipy.stats.trim_mean(x, 0.25)``; 5 runs: the mean of the middle 3)."""
    return float(_iqm(_runs(values)))


def _iqm(x: np.ndarray) -> np.ndarray:
    """:func:`iqm` of (..., tasks, runs) arrays over their last two axes."""
    from scipy import stats

    return stats.trim_mean(x.reshape(x.shape[:-2] + (-1,)), 0.25, axis=-1)


def _resample(x: np.ndarray, rng: np.random.Generator, resamples: int) -> np.ndarray:
    """(resamples, tasks, runs): runs drawn with replacement within each task."""
    tasks, runs = x.shape
    idx = rng.integers(0, runs, size=(resamples, tasks, runs))
    return np.take_along_axis(np.broadcast_to(x, (resamples, tasks, runs)), idx, axis=2)


def bootstrap_ci(
    values,
    statistic: Callable[[np.ndarray], np.ndarray] = _iqm,
    *,
    confidence: float = CONFIDENCE,
    resamples: int = RESAMPLES,
    seed: int = SEED,
) -> tuple[float, float, float]:
    """``(statistic, lo, hi)``: the statistic of ``values`` and its stratified percentile
    bootstrap interval. ``statistic`` maps (..., tasks, runs) arrays to (...) (default: the
    IQM). One run gives a degenerate interval (nothing to resample)."""
    if not 0 < confidence < 1:
        raise ValueError(f"confidence: expected a value in (0, 1), got {confidence!r}")
    x = _runs(values)
    point = float(statistic(x))
    if x.shape[1] == 1:
        return point, point, point
    rng = np.random.default_rng(seed)
    stats = statistic(_resample(x, rng, resamples))
    alpha = (1 - confidence) / 2
    lo, hi = np.quantile(stats, [alpha, 1 - alpha])
    return point, float(lo), float(hi)


def _p_less(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X < Y) + P(X = Y) / 2 over all pairs of runs of the same task, averaged over tasks;
    (..., tasks, runs) arrays -> (...)."""
    a, b = x[..., :, None], y[..., None, :]
    return ((a < b) + 0.5 * (a == b)).mean(axis=(-1, -2, -3))


def probability_of_improvement(
    x,
    y,
    *,
    confidence: float = CONFIDENCE,
    resamples: int = RESAMPLES,
    seed: int = SEED,
) -> tuple[float, float, float]:
    """``(p, lo, hi)``: the probability that a run of method X has a lower value than a run of
    method Y (lower is better: violations), ties counted one half, with a stratified bootstrap
    interval that resamples both methods' runs independently."""
    a, b = _runs(x, "x"), _runs(y, "y")
    if a.shape[0] != b.shape[0]:
        raise ValueError(f"x and y must have the same number of tasks, got {a.shape} and {b.shape}")
    point = float(_p_less(a, b))
    if a.shape[1] == 1 and b.shape[1] == 1:
        return point, point, point
    rng = np.random.default_rng(seed)
    ra, rb = _resample(a, rng, resamples), _resample(b, rng, resamples)
    stats = _p_less(ra, rb)
    alpha = (1 - confidence) / 2
    lo, hi = np.quantile(stats, [alpha, 1 - alpha])
    return point, float(lo), float(hi)


def summary(values: Sequence[float]) -> dict:
    """``{"iqm", "lo", "hi", "per_seed"}`` of one method's per-seed values (JSON-ready)."""
    point, lo, hi = bootstrap_ci(values)
    return {"iqm": point, "lo": lo, "hi": hi, "per_seed": [float(v) for v in values]}


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
