"""experiments.label_timing's report, from stand-in runs (the runs are the pipeline's)."""

import json

from experiments import label_timing


def _fake_run(per_seed, first20):
    def run(cfg):
        k = cfg.checker_train.lookahead
        n = len(per_seed[k])
        return {
            "checker": {"test": {"auroc": 0.99}},
            "methods": {"checker": {
                "training_violations_per_seed": per_seed[k],
                "training_violations_first20_per_seed": first20[k],
                "final_per_seed": {"violation_rate": [0.01] * n, "success_rate": [0.9] * n},
            }},
        }  # fmt: skip

    return run


def test_report_has_iqm_intervals_per_seed_values_and_the_comparison(tmp_path, monkeypatch):
    per_seed = {1: [10, 20, 30, 40, 50], 0: [60, 70, 80, 90, 100]}
    first20 = {1: [5, 5, 5, 5, 5], 0: [1, 1, 1, 1, 1]}
    monkeypatch.setattr(label_timing, "run_experiment", _fake_run(per_seed, first20))
    label_timing.main(["--out", str(tmp_path), "--no-progress"])
    md = (tmp_path / "label_timing.md").read_text()
    before = next(line for line in md.splitlines() if line.startswith("| just before"))
    assert "| 30 [" in before and "10, 20, 30, 40, 50 |" in before  # IQM of 10..50: 30
    assert "| 5 [5, 5] |" in before and "| 1.0 [1.0, 1.0] | 90.0 [90.0, 90.0] |" in before
    # Every just-before seed has fewer violations in all, and more in the first 20%.
    assert "than after labels): 1.00 [1.00, 1.00]; in the first 20% of training: 0.00" in md
    saved = json.loads((tmp_path / "label_timing.json").read_text())
    assert set(saved) == {"1", "0"}
