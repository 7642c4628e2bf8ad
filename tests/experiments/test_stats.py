"""experiments.stats: the interquartile mean, stratified bootstrap intervals, the
probability of improvement and Student-t intervals, against direct computations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats as sps

from experiments.stats import (
    bootstrap_ci,
    iqm,
    mean_ci,
    probability_of_improvement,
    summary,
    t_quantile,
)


@pytest.mark.parametrize("n", [4, 5, 8, 10])
def test_iqm_is_scipys_quarter_trimmed_mean(n):
    x = np.random.default_rng(n).normal(size=n)
    assert iqm(x) == pytest.approx(sps.trim_mean(x, 0.25))
    assert iqm([1, 2, 3, 4, 100]) == 3.0  # the middle three of five


def test_bootstrap_interval_holds_the_point_and_is_reproducible():
    x = [0.1, 0.4, 0.35, 0.2, 0.3, 0.25]
    point, lo, hi = bootstrap_ci(x)
    assert lo <= point <= hi and lo < hi
    assert bootstrap_ci(x) == (point, lo, hi)  # fixed generator: same report every rerun
    assert bootstrap_ci([0.7]) == (0.7, 0.7, 0.7)  # one run: nothing to resample
    assert bootstrap_ci([3, 3, 3]) == (3.0, 3.0, 3.0)


def test_bootstrap_is_stratified_per_task():
    """Each resample keeps every task's number of runs: a statistic reading task 0 only
    never sees task 1's values."""
    x = np.array([[0.0, 1.0, 2.0], [100.0, 101.0, 102.0]])
    _, lo, hi = bootstrap_ci(x, lambda r: r[..., 0, :].max(axis=-1))
    assert 0.0 <= lo <= hi <= 2.0


def test_probability_of_improvement():
    assert probability_of_improvement([1, 2, 3], [4, 5, 6])[0] == 1.0
    assert probability_of_improvement([4, 5, 6], [1, 2, 3])[0] == 0.0
    p, lo, hi = probability_of_improvement([1, 1], [1, 1])
    assert (p, lo, hi) == (0.5, 0.5, 0.5)  # ties count one half
    p, lo, hi = probability_of_improvement([1, 5], [2, 6])  # pairs: 1<2, 1<6, 5>2, 5<6
    assert p == 0.75 and 0.0 <= lo <= p <= hi <= 1.0


def test_bad_values_name_the_argument():
    with pytest.raises(ValueError, match="values: expected finite"):
        iqm([1.0, float("nan")])
    with pytest.raises(ValueError, match="x and y must have the same number of tasks"):
        probability_of_improvement([[1, 2]], [[1, 2], [3, 4]])
    with pytest.raises(ValueError, match="confidence"):
        bootstrap_ci([1, 2], confidence=1.5)


def test_summary_is_json_ready():
    s = summary(np.array([1, 2, 3, 4, 5]))
    assert set(s) == {"iqm", "lo", "hi", "per_seed"} and s["per_seed"] == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert all(type(v) is float for k, v in s.items() if k != "per_seed")


@pytest.mark.parametrize(
    "p, df, expected",
    [
        (0.975, 1, 12.706),
        (0.975, 2, 4.303),
        (0.975, 4, 2.776),
        (0.975, 9, 2.262),
        (0.975, 30, 2.042),
        (0.975, 120, 1.980),
        (0.975, math.inf, 1.960),
        (0.995, 4, 4.604),
        (0.95, 4, 2.132),
        (0.025, 4, -2.776),
        (0.5, 7, 0.0),
    ],
)
def test_t_quantile_table(p, df, expected):
    assert abs(t_quantile(p, df) - expected) < 1e-3


def test_t_quantile_fractional_df_and_symmetry():
    # df = 1 is the Cauchy distribution: quantile tan(pi (p - 1/2)).
    assert t_quantile(0.9, 1) == pytest.approx(math.tan(math.pi * 0.4), rel=1e-10)
    # df = 2 has the closed form (2p - 1) sqrt(2 / (4p(1 - p))).
    p = 0.995
    assert t_quantile(p, 2) == pytest.approx((2 * p - 1) * math.sqrt(2 / (4 * p * (1 - p))))
    assert t_quantile(0.975, 2.5) < t_quantile(0.975, 2)  # heavier tails at fewer df
    assert t_quantile(0.1, 7.5) == pytest.approx(-t_quantile(0.9, 7.5), rel=1e-12)


@pytest.mark.parametrize("p, df, name", [(1.0, 4, "p"), (0.0, 4, "p"), (0.9, 0, "df"),
                                         (0.9, -1.5, "df"), (0.9, math.nan, "df")])  # fmt: skip
def test_t_quantile_rejects_bad_input(p, df, name):
    with pytest.raises(ValueError, match=f"^{name}: "):
        t_quantile(p, df)


def test_mean_ci_known_values():
    x = [1.0, 2.0, 3.0, 4.0, 5.0]  # mean 3, s = sqrt(2.5), n = 5, df = 4
    mean, lo, hi = mean_ci(x)
    half = 2.7764451 * math.sqrt(2.5) / math.sqrt(5)
    assert isinstance(mean, float)
    assert mean == pytest.approx(3.0)
    assert lo == pytest.approx(3.0 - half, abs=1e-6)
    assert hi == pytest.approx(3.0 + half, abs=1e-6)
    # 99% is wider
    _, lo99, hi99 = mean_ci(x, confidence=0.99)
    assert lo99 < lo and hi99 > hi


def test_mean_ci_axis_and_single_seed():
    rng = np.random.default_rng(1)
    x = rng.normal(size=(4, 7))
    mean, lo, hi = mean_ci(x, axis=0)
    assert mean.shape == lo.shape == hi.shape == (7,)
    np.testing.assert_allclose(mean, x.mean(0))
    np.testing.assert_allclose(hi - mean, t_quantile(0.975, 3) * x.std(0, ddof=1) / 2)
    mean1, lo1, hi1 = mean_ci(x, axis=1)
    assert mean1.shape == (4,)
    # one seed: degenerate interval
    m, lo, hi = mean_ci([0.25])
    assert m == lo == hi == 0.25
    m, lo, hi = mean_ci(x[:1], axis=0)
    np.testing.assert_array_equal(lo, m)
    np.testing.assert_array_equal(hi, m)
    with pytest.raises(ValueError):
        mean_ci([])
