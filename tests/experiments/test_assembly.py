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
