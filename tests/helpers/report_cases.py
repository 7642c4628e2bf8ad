"""Shared cases for the report's tests: a valid ``results.json`` object of every mode, whose
methods carry per-seed finals (``tests/experiments/conftest.py`` serves it as ``good``)."""

from __future__ import annotations

import numpy as np

METRICS = {"accuracy": 0.97, "precision": 0.9, "recall": 0.88, "f1": 0.89, "auroc": 0.99,
           "ece": 0.02}  # fmt: skip


def method(viol: float, reward: float, success: float, seeds: int = 3) -> dict:
    rng = np.random.default_rng(0)
    return {
        "final": {
            "violation_rate": viol,
            "mean_reward": reward,
            "success_rate": success,
            "episodes": 500,
        },
        "training_violations": 1234,
        "curve": [
            {"step": s, "violation_rate": viol, "mean_reward": reward, "success_rate": success}
            for s in (0, 10_000, 20_000)
        ],
        "seeds": seeds,
        "final_per_seed": {
            "violation_rate": np.clip(viol + 0.01 * rng.standard_normal(seeds), 0, 1).tolist(),
            "mean_reward": (reward + 0.02 * rng.standard_normal(seeds)).tolist(),
            "success_rate": [success] * seeds,
        },
    }


def results() -> dict:
    """A fresh valid results object: six modes, three seeds each, a null transfer."""
    return {
        "experiment": "two_rooms",
        "config": {"steps": 20_000, "seeds": 3},
        "checker": {"test": dict(METRICS), "heldout": dict(METRICS), "transfer": None},
        "methods": {
            "checker": method(0.02, 0.91, 0.97),
            "shaped": method(0.01, 0.92, 0.98),
            "none": method(0.35, 0.93, 0.99),
            "lagrangian": method(0.05, 0.85, 0.95),
            "shield": {
                **method(0.0, 0.90, 0.96),
                "final_unshielded": {
                    "violation_rate": 0.04,
                    "mean_reward": 0.88,
                    "success_rate": 0.95,
                    "episodes": 500,
                },
            },
            "shield_monitor": method(0.0, 0.91, 0.97),
        },
        "timing": {"total_s": 123.4},
        "extra_top_level": {"anything": [1, 2, 3]},
    }


#: Per-seed cost metrics of :func:`with_costs` (three seeds).
COSTS = {"mean_cost": [0.2, 0.4, 0.6], "mean_costly_run": [1.0, 1.5, 2.0],
         "max_costly_run": [3.0, 4.0, 8.0]}  # fmt: skip
COST_RATES = [0.001, 0.002, 0.003]


def with_costs(results: dict) -> dict:
    """``results`` (of :func:`results`) with the cost metrics as ``experiments.assembly``
    writes them: pooled and per-seed finals, the training cost rate, their IQM summaries."""
    from experiments.stats import summary

    for entry in results["methods"].values():
        entry["final"].update({k: float(np.mean(v)) for k, v in COSTS.items()},
                              max_costly_run=max(COSTS["max_costly_run"]))  # fmt: skip
        entry["final_per_seed"].update({k: list(v) for k, v in COSTS.items()})
        entry["training_cost_rate"] = float(np.mean(COST_RATES))
        entry["training_cost_rate_per_seed"] = list(COST_RATES)
        entry["training_cost_per_seed"] = [r * 20_000 for r in COST_RATES]
        entry["training_violations_per_seed"] = [1234] * entry["seeds"]
        entry["iqm"] = {k: summary(v) for k, v in
                        {**COSTS, "training_cost_rate": COST_RATES}.items()}  # fmt: skip
        if "final_unshielded" in entry:
            entry["final_unshielded"].update(mean_cost=0.9)
    return results
