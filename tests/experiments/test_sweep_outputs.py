"""``--sweep NAME=V1,V2``: the flag, the split of one swept run into per-value results, and
the summary (from stand-in runs shaped like ``agents.runner.run``'s; training a sweep is
``tests/agents/test_sweep.py``'s)."""

import json

import numpy as np
import pytest

from experiments import assembly, pipeline, two_rooms
from experiments.report import validate_results

CHECKER = {"accuracy": 0.9, "precision": 0.9, "recall": 0.9, "f1": 0.9, "auroc": 0.95,
           "ece": 0.01}  # fmt: skip
VALUES = (0.3, 1.0)
SEEDS = 3


def _swept_run(shift: float) -> dict:
    """Agents (value, seed): 0.3 x seeds 0-2, then 1.0 x seeds 0-2; final success rises with
    the value and the seed, training violations fall with the value."""
    agents = len(VALUES) * SEEDS
    value = np.repeat(VALUES, SEEDS)
    seed = np.tile(np.arange(SEEDS), len(VALUES))
    rates = {k: np.full((agents, 2), 0.5) for k in ("violation_rate", "mean_reward",
                                                    "success_rate")}  # fmt: skip
    final = {"violation_rate": 0.1 / value * 0.1 + shift, "mean_reward": 0.5 + 0 * value,
             "success_rate": 0.5 * value + 0.01 * seed}  # fmt: skip
    records = [{"seed": int(s), "penalty": float(v), "chunk": c}
               for c in range(2) for v, s in zip(value, seed, strict=True)]  # fmt: skip
    return {"steps": np.array([100, 200]), "eval": rates, "final": final,
            "seeds": seed.tolist(), "sweep": {"penalty": value},
            "train_violations": (100 / value).astype(int) + seed,
            "train_violations_early": (10 / value).astype(int),
            "train_alarms": np.zeros(agents), "wall_s": 2.0, "records": records,
            "params": {"w": np.arange(agents * 2.0).reshape(agents, 2)}}  # fmt: skip


def _cfg(tmp_path, *flags):
    argv = ["--quick", "--seeds", str(SEEDS), "--out", str(tmp_path), *flags]
    return pipeline.parse_args(argv, two_rooms.SCENARIO)


def test_select_agents_is_the_run_of_one_value():
    run = _swept_run(0.0)
    part = assembly.select_agents(run, "penalty", 1.0)
    assert part["seeds"] == [0, 1, 2] and "sweep" not in part
    np.testing.assert_array_equal(part["train_violations"], [100, 101, 102])
    np.testing.assert_allclose(part["final"]["success_rate"], [0.5, 0.51, 0.52])
    np.testing.assert_array_equal(part["params"]["w"], [[6, 7], [8, 9], [10, 11]])
    assert [r["penalty"] for r in part["records"]] == [1.0] * 6


def test_sweep_writes_results_per_value_and_a_summary(tmp_path):
    cfg = _cfg(tmp_path, "--sweep", "penalty=0.3,1", "--modes", "checker,shaped")
    runs = {"checker": _swept_run(0.0), "shaped": _swept_run(0.05)}
    summary = assembly.write_sweep(cfg, tmp_path, runs, {"test": CHECKER, "heldout": None}, 9.0)
    for value in ("0.3", "1"):
        results = json.loads((tmp_path / f"penalty={value}" / "results.json").read_text())
        validate_results(results)
        assert results["sweep"] == {"penalty": float(value)}
        assert results["config"]["ppo"]["penalty"] == float(value)
        assert results["methods"]["checker"]["seeds"] == SEEDS
    rows = {(r["penalty"], r["mode"]): r for r in summary["rows"]}
    assert rows[1.0, "checker"]["success_rate"]["iqm"] == pytest.approx(0.51)
    assert rows[0.3, "shaped"]["training_violations"]["per_seed"] == [333, 334, 335]
    md = (tmp_path / "sweep.md").read_text()
    assert "| 1 | checker | 1.0 [" in md and "| checker | 6 |" in md
    assert (tmp_path / "sweep.png").stat().st_size > 1000
    assert summary["throughput"]["checker"]["steps_per_s"] == pytest.approx(200 * 6 / 2.0)


@pytest.mark.parametrize(
    ("flag", "message"),
    [
        ("gamma=0.9,0.99", "cannot sweep 'gamma'"),
        ("penalty", "expected NAME=V1,V2"),
        ("penalty=0.1,0.1", "distinct"),
        ("penalty=0.1,x", "must be numbers"),
        ("checker_threshold=0.5,1.5", "--checker-threshold must be in (0, 1), got 1.5"),
    ],
)
def test_a_bad_sweep_is_a_usage_error_naming_the_flag(tmp_path, capsys, flag, message):
    with pytest.raises(SystemExit) as e:
        _cfg(tmp_path, "--sweep", flag)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "sweep" in err and message in err
