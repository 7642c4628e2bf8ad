"""experiments.assembly: the results.json object of the modes' runs (stand-in runs shaped
like ``agents.runner.run``'s)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.report_cases import METRICS

from experiments import assembly, pipeline, two_rooms
from experiments.report import results_table, validate_results


def _run(seeds: int, violations, early, shield: bool = False) -> dict:
    """A finished PPO run as ``agents.runner.run`` returns it (two evaluations)."""
    rates = {k: np.full((seeds, 2), 0.5) for k in ("violation_rate", "mean_reward",
                                                   "success_rate")}  # fmt: skip
    final = {k: np.linspace(0.0, 0.2, seeds) for k in ("violation_rate", "mean_reward",
                                                       "success_rate")}  # fmt: skip
    if shield:
        final["unshielded"] = {k: v + 0.5 for k, v in final.items()}
    return {"steps": np.array([100, 200]), "eval": rates, "final": final,
            "seeds": list(range(seeds)), "train_violations": np.asarray(violations),
            "train_violations_early": np.asarray(early), "train_alarms": np.zeros(seeds),
            "wall_s": 1.0, "records": []}  # fmt: skip


def test_assembled_results_hold_shields_early_violations_and_comparisons(tmp_path):
    cfg = pipeline.parse_args(["--quick", "--seeds", "5", "--out", str(tmp_path)],
                              two_rooms.SCENARIO)  # fmt: skip
    runs = {"checker": _run(5, [10, 20, 30, 40, 50], [1, 2, 3, 4, 5]),
            "shaped": _run(5, [60, 70, 80, 90, 100], [5, 6, 7, 8, 9]),
            "shield": _run(5, [0, 0, 1, 0, 2], [0, 0, 0, 0, 1], shield=True)}  # fmt: skip
    report = {"test": dict(METRICS), "heldout": None}
    results = assembly.assemble(cfg, tmp_path, runs, report, 12.0)
    validate_results(results)
    assert results["config"]["penalty_start"] == 0.0
    shield = results["methods"]["shield"]
    assert shield["final_unshielded"]["violation_rate"] == pytest.approx(0.6)
    assert shield["training_violations_first20_per_seed"] == [0, 0, 0, 0, 1]
    assert shield["iqm"]["training_violations"]["iqm"] == pytest.approx(1 / 3)
    checker = results["methods"]["checker"]
    assert checker["training_violations_first20"] == 3
    assert checker["iqm"]["training_violations"]["per_seed"] == [10, 20, 30, 40, 50]
    comparisons = results["comparisons"]
    assert comparisons["checker_beats_shaped_training_violations"]["p"] == 1.0
    # 24 of the 25 pairs of seeds have fewer early violations, one (5 and 5) ties: a half
    assert comparisons["checker_beats_shaped_training_violations_first20"]["p"] == 24.5 / 25
    assert set(comparisons) == {f"{x}_beats_shaped_{k}" for x in ("checker", "shield")
                                for k in ("training_violations",
                                          "training_violations_first20")}  # fmt: skip
    assert "shield off" in results_table(results)
    assert "Episode cost" not in results_table(results)  # runs without the cost metrics


def _costly_run(shield: bool = False) -> dict:
    """A run of three seeds with the cost metrics of ``agents.runner.run``'s result."""
    r = _run(3, [3, 4, 5], [1, 1, 1], shield=shield)
    costs = {"mean_cost": np.array([0.5, 1.0, 3.0]), "mean_costly_run": np.array([1.0, 1.0, 2.5]),
             "max_costly_run": np.array([2.0, 3.0, 9.0])}  # fmt: skip
    r["final"].update(costs)
    if shield:
        r["final"]["unshielded"].update({k: v + 1 for k, v in costs.items()})
    r["eval"].update({k: np.full((3, 2), 0.25) for k in costs})
    # Cost over training so far after each of the two evaluations (steps 100 and 200).
    r["train_env_cost"] = np.array([2.0, 4.0, 10.0])
    r["train_cost_rate"] = np.array([[0.01, 0.01], [0.0, 0.02], [0.05, 0.05]])
    return r


def test_assembled_results_hold_the_cost_metrics_per_seed(tmp_path):
    cfg = pipeline.parse_args(["--quick", "--seeds", "3", "--out", str(tmp_path)],
                              two_rooms.SCENARIO)  # fmt: skip
    runs = {"shaped": _costly_run(), "shield": _costly_run(shield=True),
            "none": _run(3, [1, 2, 3], [0, 0, 0])}  # fmt: skip
    results = assembly.assemble(cfg, tmp_path, runs, {"test": dict(METRICS), "heldout": None},
                                1.0)  # fmt: skip
    validate_results(results)
    shaped = results["methods"]["shaped"]
    # Pooled over seeds: the mean of the means, the maximum of the maxima.
    assert shaped["final"]["mean_cost"] == pytest.approx(1.5)
    assert shaped["final"]["max_costly_run"] == 9.0
    assert shaped["final_per_seed"]["mean_costly_run"] == [1.0, 1.0, 2.5]
    assert shaped["iqm"]["max_costly_run"]["iqm"] == pytest.approx(14 / 3)  # three seeds: mean
    assert shaped["training_cost_rate_per_seed"] == [0.01, 0.02, 0.05]  # after the last update
    assert shaped["training_cost_rate"] == pytest.approx(0.08 / 3)
    assert shaped["training_cost_per_seed"] == [2.0, 4.0, 10.0]
    assert shaped["training_violations_per_seed"] == [3, 4, 5]
    assert shaped["iqm"]["training_cost_rate"]["per_seed"] == [0.01, 0.02, 0.05]
    assert shaped["curve_per_seed"]["training_cost_rate"][1] == [0.0, 0.02]
    assert shaped["curve_per_seed"]["mean_cost"] == [[0.25, 0.25]] * 3
    assert shaped["curve"][0]["max_costly_run"] == 0.25
    shield = results["methods"]["shield"]
    assert shield["final_unshielded"]["max_costly_run"] == 10.0
    assert shield["iqm"]["unshielded_mean_cost"]["per_seed"] == [1.5, 2.0, 4.0]
    # A run without them (older than the metrics) has none, and its rows say n/a.
    assert "mean_cost" not in results["methods"]["none"]["final"]
    assert "training_cost_rate" not in results["methods"]["none"]
    row = next(ln for ln in results_table(results).splitlines()
               if ln.startswith("| none (unconstrained) | n/a"))  # fmt: skip
    assert row == "| none (unconstrained) | n/a | n/a | n/a | n/a |"
