"""experiments.report.tables: the Markdown tables, results.json + results.md, the console
summary."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.report_cases import COST_RATES, COSTS, METRICS, with_costs

from agents.config import PAPER_MODES as MODES  # the fixture's modes
from experiments.report import results_table, summarise, validate_results, write_report


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


def _iqm_cell(values, scale: float, digits: int) -> str:
    from experiments.stats import summary

    point, lo, hi = (summary(values)[k] * scale for k in ("iqm", "lo", "hi"))
    return f"{point:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def test_the_cost_metrics_have_their_own_table_where_the_results_hold_them(good):
    assert "Episode cost" not in results_table(good)  # results written before them
    assert " cost " not in summarise(good)
    md = results_table(with_costs(good))
    rows = [ln for ln in md.splitlines() if ln.startswith("| ")]
    header = next(i for i, ln in enumerate(rows) if ln.startswith("| Method | Episode cost"))
    cost_rows = rows[header + 1 :]
    expected = " | ".join([_iqm_cell(COSTS["mean_cost"], 1, 3),
                           _iqm_cell(COSTS["mean_costly_run"], 1, 2),
                           _iqm_cell(COSTS["max_costly_run"], 1, 1),
                           _iqm_cell(COST_RATES, 1, 4)])  # fmt: skip
    assert f"| checker (checker-shaped) | {expected} |" in cost_rows
    assert expected.startswith("0.400 [0.200, 0.600] | 1.50 [")  # three seeds: their mean
    # A shield's policy alone: its pooled episode cost; the same training.
    off = next(ln for ln in cost_rows if ln.startswith("| shield (checker shield, shield off)"))
    assert off.split(" | ")[1:3] == ["0.900", "n/a"] and off.endswith(
        f"| {_iqm_cell(COST_RATES, 1, 4)} |"
    )
    assert "cost 0.400 [0.200, 0.600]" in summarise(with_costs(good))
