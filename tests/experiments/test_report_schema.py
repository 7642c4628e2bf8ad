"""experiments.report.schema: the results.json contract, its check and the modes' order."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.report_cases import with_costs

from experiments.report import MODES, checker_rates, validate_results
from jaxgrid.io import read_json

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "results"


def test_validate_accepts_good(good):
    validate_results(good)
    # heldout may be null; numpy scalars are fine; extra keys are fine
    good["checker"]["heldout"] = None
    good["methods"]["none"]["final"]["episodes"] = np.int64(500)
    good["methods"]["none"]["final"]["mean_reward"] = np.float32(0.5)
    good["methods"]["none"]["per_seed_extra"] = [1, 2]
    validate_results(good)
    # a subset of modes is fine
    del good["methods"]["lagrangian"]
    validate_results(good)


def _mutate(results, path, value=KeyError):
    """Set (or, with the default, delete) the item at a tuple ``path``."""
    d = results
    for k in path[:-1]:
        d = d[k]
    if value is KeyError:
        del d[path[-1]]
    else:
        d[path[-1]] = value
    return results


@pytest.mark.parametrize(
    "path, value, expected",
    [
        # missing keys
        (("experiment",), KeyError, "experiment: missing"),
        (("timing", "total_s"), KeyError, "timing.total_s: missing"),
        (("checker", "heldout"), KeyError, "checker.heldout: missing"),
        (("methods", "shaped", "training_violations"), KeyError,
         "methods.shaped.training_violations: missing"),
        (("methods", "none", "curve", 1, "success_rate"), KeyError,
         "methods.none.curve[1].success_rate: missing"),
        # rates out of range
        (("methods", "checker", "final", "violation_rate"), 1.3,
         "methods.checker.final.violation_rate: expected a float in [0, 1], got 1.3"),
        (("checker", "test", "auroc"), -0.1, "checker.test.auroc: expected a float in [0, 1]"),
        (("methods", "shaped", "curve", 2, "violation_rate"), float("nan"),
         "methods.shaped.curve[2].violation_rate"),
        (("methods", "checker", "final_per_seed", "success_rate", 1), 2.0,
         "methods.checker.final_per_seed.success_rate[1]: expected a float in [0, 1]"),
        # wrong types
        (("experiment",), 3, "experiment: expected a non-empty str"),
        (("methods", "none", "final", "episodes"), 500.5,
         "methods.none.final.episodes: expected an int >= 1"),
        (("methods", "none", "final", "episodes"), "500",
         "methods.none.final.episodes: expected an int >= 1"),
        (("methods", "none", "seeds"), True, "methods.none.seeds: expected an int >= 1"),
        (("methods", "lagrangian", "training_violations"), -1,
         "methods.lagrangian.training_violations: expected an int >= 0"),
        (("methods", "checker", "final", "mean_reward"), "high",
         "methods.checker.final.mean_reward: expected a finite float"),
        (("methods", "checker", "curve"), "nope", "methods.checker.curve: expected a list"),
        (("config",), [], "config: expected an object"),
        (("checker", "heldout"), [0.9], "checker.heldout: expected an object"),
        (("timing", "total_s"), -5.0, "timing.total_s: expected a float >= 0.0"),
        # structure
        (("methods", "checker", "curve", 2, "step"), 5,
         "methods.checker.curve[2].step: steps must be non-decreasing"),
        (("methods", "checker", "final_per_seed", "mean_reward"), [0.1],
         "methods.checker.final_per_seed.mean_reward: expected 3 values"),
        (("methods",), {}, "methods: expected at least one mode"),
    ],
)  # fmt: skip
def test_validate_rejects_with_path(good, path, value, expected):
    bad = _mutate(copy.deepcopy(good), path, value)
    with pytest.raises(ValueError) as err:
        validate_results(bad)
    assert str(err.value).startswith(expected), str(err.value)


def test_validate_rejects_unknown_mode(good):
    good["methods"]["ppo_magic"] = good["methods"]["none"]
    with pytest.raises(ValueError, match=r"^methods\.ppo_magic: unknown mode 'ppo_magic'"):
        validate_results(good)


def test_validate_rejects_non_dict():
    with pytest.raises(ValueError, match="expected an object"):
        validate_results([1, 2])


def test_modes_are_the_learners_reward_modes_in_display_order():
    from agents.config import REWARD_MODES

    assert MODES is REWARD_MODES and MODES[0] == "checker"


def test_import_without_scipy_stats_matplotlib():
    code = (
        "import sys, experiments.report; "
        "bad = [m for m in ('scipy.stats', 'matplotlib') if m in sys.modules]; "
        "assert not bad, bad"
    )
    root = Path(__file__).resolve().parents[2]
    subprocess.run([sys.executable, "-c", code], check=True, cwd=root)


def test_checker_rates_fill_what_a_checker_evaluation_leaves_undefined():
    metrics = {"accuracy": 0.9, "precision": None, "recall": 0.0, "f1": None, "auroc": None,
               "ece": 0.1, "n": 40}  # fmt: skip
    assert checker_rates(metrics) == {"accuracy": 0.9, "precision": 0.0, "recall": 0.0,
                                      "f1": 0.0, "auroc": 0.5, "ece": 0.1}  # fmt: skip


def test_the_cost_metrics_are_optional_and_checked_where_present(good):
    validate_results(good)  # results written before the cost metrics
    costly = with_costs(copy.deepcopy(good))
    validate_results(costly)
    for path, value, expected in [
        (("final", "mean_cost"), -0.1, "final.mean_cost: expected a float >= 0.0"),
        (("final", "max_costly_run"), float("nan"), "final.max_costly_run: expected a finite"),
        (("final_per_seed", "mean_costly_run"), [1.0], "final_per_seed.mean_costly_run: "
         "expected 3 values"),
        (("final_per_seed", "max_costly_run", 2), -1.0, "final_per_seed.max_costly_run[2]"),
        (("training_cost_rate",), "low", "training_cost_rate: expected a finite float"),
        (("training_cost_rate_per_seed", 0), -0.5, "training_cost_rate_per_seed[0]: expected "
         "a float >= 0.0"),
        (("training_cost_per_seed",), [1.0, 2.0], "training_cost_per_seed: expected 3 values"),
        (("training_violations_per_seed", 1), 2.5, "training_violations_per_seed[1]: expected "
         "an int >= 0"),
    ]:  # fmt: skip
        bad = _mutate(copy.deepcopy(costly), ("methods", "shaped", *path), value)
        with pytest.raises(ValueError) as err:
            validate_results(bad)
        assert str(err.value).startswith(f"methods.shaped.{expected}"), str(err.value)


@pytest.mark.parametrize("name", sorted(p.parent.name for p in RESULTS.glob("*/results.json")))
def test_published_results_written_before_the_cost_metrics_still_validate(name):
    validate_results(read_json(RESULTS / name / "results.json"))
