"""experiments.report: results schema, statistics, figure, tables, files."""

from __future__ import annotations

import copy
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from experiments import report
from experiments.report import (
    MODES,
    plot_curves,
    results_table,
    summarise,
    validate_results,
    write_report,
)
from experiments.stats import mean_ci, t_quantile

METRICS = {"accuracy": 0.97, "precision": 0.9, "recall": 0.88, "f1": 0.89, "auroc": 0.99,
           "ece": 0.02}  # fmt: skip


def _method(viol: float, reward: float, success: float, seeds: int = 3) -> dict:
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


@pytest.fixture
def good() -> dict:
    return {
        "experiment": "two_rooms",
        "config": {"steps": 20_000, "seeds": 3},
        "checker": {"test": dict(METRICS), "heldout": dict(METRICS), "transfer": None},
        "methods": {
            "checker": _method(0.02, 0.91, 0.97),
            "shaped": _method(0.01, 0.92, 0.98),
            "none": _method(0.35, 0.93, 0.99),
            "lagrangian": _method(0.05, 0.85, 0.95),
            "shield": {
                **_method(0.0, 0.90, 0.96),
                "final_unshielded": {
                    "violation_rate": 0.04,
                    "mean_reward": 0.88,
                    "success_rate": 0.95,
                    "episodes": 500,
                },
            },
            "shield_monitor": _method(0.0, 0.91, 0.97),
        },
        "timing": {"total_s": 123.4},
        "extra_top_level": {"anything": [1, 2, 3]},
    }


# --- validate_results -------------------------------------------------------------------------


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


# --- statistics -------------------------------------------------------------------------------


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


# --- figure -----------------------------------------------------------------------------------


def _curves(seeds=3, steps=12):
    rng = np.random.default_rng(2)
    t = np.linspace(0, 1e6, steps)
    out = {}
    for i, mode in enumerate(MODES):
        base = np.exp(-t / 3e5) * (0.1 + 0.2 * i)
        out[mode] = {
            "step": t,
            "violation_rate": np.clip(base + 0.02 * rng.standard_normal((seeds, steps)), 0, 1),
            "mean_reward": 1 - np.exp(-t / 2e5) + 0.05 * rng.standard_normal((seeds, steps)),
        }
    out["none"]["success_rate"] = np.ones((seeds, steps))
    return out


def test_plot_curves_writes_png(tmp_path):
    import imageio.v3 as iio

    path = plot_curves(_curves(), tmp_path / "sub" / "curves.png", title="TwoRooms")
    assert path.exists() and path.stat().st_size > 10_000
    img = iio.imread(path)
    assert img.shape[:2] == (504, 1320)  # figsize (11, 4.2) at 120 dpi
    # not a blank canvas: several distinct colours drawn
    assert len(np.unique(img.reshape(-1, img.shape[-1]), axis=0)) > 50
    assert not list(tmp_path.glob("sub/*.tmp"))


def test_plot_curves_single_seed_and_1d(tmp_path):
    import matplotlib.image

    c = {"checker": {"step": [0, 1, 2], "violation_rate": [0.5, 0.2, 0.1],
                     "mean_reward": [0.0, 0.4, 0.8]}}  # fmt: skip
    path = plot_curves(c, tmp_path / "one.png", dpi=50, figsize=(6, 3))
    assert matplotlib.image.imread(path).shape[:2] == (150, 300)


def test_plot_curves_rejects_bad_shape(tmp_path):
    c = _curves()
    c["shaped"]["mean_reward"] = c["shaped"]["mean_reward"][:, :-1]
    with pytest.raises(ValueError, match="shaped.mean_reward"):
        plot_curves(c, tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_curves_from_results(good, tmp_path):
    c = report.curves_from_results(good)
    assert set(c) == set(MODES)
    assert c["checker"]["violation_rate"].shape == (1, 3)
    good["methods"]["none"]["curve_per_seed"] = _curves()["none"]
    c = report.curves_from_results(good)
    assert c["none"]["violation_rate"].shape == (3, 12)


# --- tables, files, console -------------------------------------------------------------------


def test_results_table(good):
    md = results_table(good)
    rows = [ln for ln in md.splitlines() if ln.startswith("| ")]
    for mode in MODES:
        assert any(ln.startswith(f"| {mode} ") for ln in rows), mode
    assert "±" in md  # per-seed CI shown
    assert "| 1234 |" in md and "| 500 |" in md
    assert any(ln.startswith("| shield (checker shield, shield off) | 4.0 |") for ln in rows)
    assert any(ln.startswith("| test |") and "0.990" in ln for ln in rows)
    assert any(ln.startswith("| heldout |") for ln in rows)
    assert not any(ln.startswith("| transfer |") for ln in rows)  # null -> omitted
    # canonical order
    assert md.index("| checker ") < md.index("| shaped ") < md.index("| none ")
    # without per-seed values: plain finals; null heldout -> n/a; transfer shown
    for e in good["methods"].values():
        del e["final_per_seed"]
    good["checker"]["heldout"] = None
    good["checker"]["transfer"] = dict(METRICS)
    md = results_table(good)
    assert "±" not in md.split("Interquartile mean")[0]
    assert "| 2.0 |" in md  # checker violation 0.02 -> 2.0 %
    assert "| heldout | n/a |" in md
    assert "| transfer |" in md


def test_results_table_shows_iqm_intervals_and_comparisons(good):
    from experiments.stats import summary

    entry = good["methods"]["checker"]
    entry["iqm"] = {"violation_rate": summary([0.0, 0.01, 0.02, 0.03, 0.5]),
                    "training_violations": summary([10, 20, 30, 40, 5000])}  # fmt: skip
    good["comparisons"] = {"checker_beats_shaped_training_violations_first20":
                           {"p": 0.8, "lo": 0.55, "hi": 1.0}}  # fmt: skip
    md = results_table(good)
    row = next(ln for ln in md.splitlines() if ln.startswith("| checker "))
    assert "| 2.0 [" in row  # IQM of the middle three: 1, 2, 3 %
    assert "| 30 [" in row  # the outlying seed does not move the IQM
    assert "| P(checker has fewer violations than shaped in the first 20% of training) | 0.80 " \
           "| [0.55, 1.00] |" in md  # fmt: skip


def test_write_report(good, tmp_path):
    good["methods"]["checker"]["extra_array"] = np.arange(3)
    good["methods"]["checker"]["nan_extra"] = float("nan")
    paths = write_report(good, tmp_path / "run")
    json_path, md_path = paths
    assert json_path == paths.json == tmp_path / "run" / "results.json"
    data = json.loads(json_path.read_text())
    validate_results(data)
    assert data["methods"]["checker"]["extra_array"] == [0, 1, 2]
    assert data["methods"]["checker"]["nan_extra"] is None
    md = md_path.read_text()
    assert md.startswith("# Results: two_rooms") and "| lagrangian " in md
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["results.json", "results.md"]


def test_results_md_names_the_machine_baseline_beside_the_run_time(good, tmp_path):
    md = write_report(good, tmp_path / "a").md.read_text()
    assert "Total wall time:" in md and "PureJaxRL" not in md  # not measured: nothing said
    good["timing"]["machine_baseline"] = {"env": "MiniGrid-DoorKey-8x8-v0", "sps": 61234.5,
                                          "device": "cpu (2 cores visible)"}  # fmt: skip
    md = write_report(good, tmp_path / "b").md.read_text()
    line = next(x for x in md.splitlines() if x.startswith("Total wall time:"))
    assert "61,234 steps/s" in line and "--env MiniGrid-DoorKey-8x8-v0" in line
    assert "cpu (2 cores visible)" in line


def test_write_report_refuses_invalid(good, tmp_path):
    write_report(good, tmp_path)
    before = (tmp_path / "results.json").read_bytes()
    good["methods"]["checker"]["final"]["violation_rate"] = 1.3
    with pytest.raises(ValueError, match=r"methods\.checker\.final\.violation_rate"):
        write_report(good, tmp_path)
    assert (tmp_path / "results.json").read_bytes() == before  # old file untouched
    with pytest.raises(ValueError):
        write_report(good, tmp_path / "fresh")
    assert not (tmp_path / "fresh").exists()  # nothing created


def test_summarise(good):
    s = summarise(good)
    lines = s.splitlines()
    assert lines[0] == "two_rooms:"
    for mode in MODES:
        assert any(ln.strip().startswith(mode) for ln in lines), mode
    assert "checker AUROC: test 0.990, heldout 0.990" in s
    assert "total time: 2m 03s" in s


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
    from experiments import assembly, pipeline, two_rooms

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


def test_the_shields_own_checker_is_validated_tabled_and_summarised(good):
    by = {"avoid": 0.999, "budget": 0.99, "sequential": None, "late_budget": 0.98}
    good["checker"]["auroc_by"] = by
    good["checker"]["shield"] = {"test": {**METRICS, "auroc": 0.987}, "guided": 0.5,
                                 "auroc_by": {**by, "budget": 0.95}}  # fmt: skip
    validate_results(good)
    md = results_table(good)
    assert "| test, shield's checker (guided 0.5) |" in md and " 0.987 |" in md
    assert "| memory checker | 0.999 | 0.990 | n/a | 0.980 |" in md
    assert "| shield's checker | 0.999 | 0.950 | n/a | 0.980 |" in md
    assert "shield's checker 0.987" in summarise(good)
    good["checker"]["shield"]["test"]["auroc"] = 1.5
    with pytest.raises(ValueError, match=r"^checker\.shield\.test\.auroc: expected a float"):
        validate_results(good)
