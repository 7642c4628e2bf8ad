"""experiments.stats: the interquartile mean, stratified bootstrap intervals and the
probability of improvement, against direct computations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats as sps

from experiments.stats import bootstrap_ci, iqm, probability_of_improvement, summary


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
