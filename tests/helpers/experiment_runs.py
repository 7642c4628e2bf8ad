"""Shared by the experiments' tests: ``--quick`` pipeline runs in this process, and the check
of their outputs (files, schema, seeds and episodes of the quick preset)."""

from __future__ import annotations

import json

from agents.config import PAPER_MODES
from experiments import pipeline
from experiments.report import COST_KEYS, validate_results

OUTPUTS = ("results.json", "results.md", "curves.png", "checker.json", "episodes.gif",
           "metrics.jsonl", "config.json")  # fmt: skip


def quick(module, out, *extra) -> dict:
    """``python -m experiments.<module> --quick --no-progress --out OUT ...``, in process."""
    argv = ["--quick", "--no-progress", "--out", str(out), *extra]
    return pipeline.main(module.SCENARIO, argv)


def check_outputs(out, experiment: str, modes=PAPER_MODES, seeds=2, final_episodes=32) -> dict:
    """Every output of a ``--quick`` run in ``out`` exists and follows the schema."""
    for name in OUTPUTS:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    results = json.loads((out / "results.json").read_text())
    validate_results(results)
    assert results["experiment"] == experiment
    assert set(results["methods"]) == set(modes)
    for entry in results["methods"].values():
        assert entry["seeds"] == seeds
        assert entry["final"]["episodes"] == seeds * final_episodes
        assert len(entry["curve"]) >= 1
        # The field's cost metrics, per seed and summarised.
        assert set(COST_KEYS) <= set(entry["final_per_seed"]) and set(COST_KEYS) <= set(
            entry["iqm"]
        )
        for k in ("training_cost_rate_per_seed", "training_violations_per_seed"):
            assert len(entry[k]) == seeds, k
        assert len(entry["curve_per_seed"]["training_cost_rate"][0]) == len(entry["curve"])
    assert "| Method | Episode cost |" in (out / "results.md").read_text()
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert {r["mode"] for r in records} == set(modes)
    assert (out / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "episodes.gif").read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    return results


def refused_before_any_compile(module, out, argv, message, capsys, compiles) -> None:
    """``--quick`` with ``argv`` exits with status 2 and ``message`` on stderr, before any
    compile and without creating ``out``."""
    import pytest

    with pytest.raises(SystemExit) as exc:
        quick(module, out, *argv)
    assert exc.value.code == 2
    err = " ".join(capsys.readouterr().err.replace("│", " ").split())
    assert message in err, err
    assert not out.exists() and not compiles
