"""``python -m experiments.benchmark``: its flags, its routing through the one pipeline, its
read-back of finished levels, its table and pictures."""

from __future__ import annotations

import json

import pytest

from experiments import benchmark
from experiments.presets import BENCHMARK_LEVELS, EXPERIMENTS


def _fake_results(cfg) -> dict:
    """A level's results as the pipeline writes them, with figures that name the cell."""
    base = BENCHMARK_LEVELS.index(cfg.experiment)

    def summary(x):
        return {"iqm": x, "lo": x - 0.01, "hi": x + 0.01, "per_seed": [x] * cfg.seeds}

    methods = {m: {"iqm": {"violation_rate": summary(0.1 * base), "success_rate": summary(0.5),
                           "mean_reward": summary(0.4), "training_violations": summary(10.0 + i)}}
               for i, m in enumerate(cfg.modes)}  # fmt: skip
    config = {**benchmark.config_dict(cfg), "penalty_start": 0.5}  # assembly adds keys
    return {"methods": methods, "timing": {"total_s": 1.0}, "config": config}


def _write_results(out, cfg) -> dict:
    """:func:`_fake_results` of ``cfg``, written where the pipeline writes a level's."""
    results = _fake_results(cfg)
    (out / cfg.experiment).mkdir(parents=True, exist_ok=True)
    (out / cfg.experiment / "results.json").write_text(json.dumps(results))
    return results


@pytest.mark.parametrize(("argv", "message"), [
    (["--levels", "two_rooms,nowhere"], "--levels: unknown"),
    (["--methods", "none,bogus"], "--methods: unknown"),
    (["--methods", "none,none"], "repeated"),
    (["--levels", "label_timing"], "--levels: unknown"),  # an ablation, not a level
    (["--seeds", "0"], "--seeds must be an integer >= 1"),
    (["--methods", "none,shield", "--constrained-cost", "monitor"], "no mode of none,shield"),
])  # fmt: skip
def test_bad_flags_are_refused_before_any_compile(argv, message, tmp_path, capsys, compiles):
    with pytest.raises(SystemExit) as exc:
        benchmark.main(["--quick", "--out", str(tmp_path / "b"), *argv])
    assert exc.value.code == 2
    assert message in " ".join(capsys.readouterr().err.replace("│", " ").split())
    assert not (tmp_path / "b").exists() and not compiles


def test_every_level_runs_through_the_pipeline_then_one_table(tmp_path, monkeypatch):
    """Each level is its row's quick preset with the methods and seeds asked for, in
    OUT/<level>; a second call reads finished levels back instead of running them."""
    ran = []

    def run(cfg):
        ran.append(cfg)
        return _write_results(tmp_path / "b", cfg)

    monkeypatch.setattr(benchmark, "run_experiment", run)
    argv = ["--quick", "--no-progress", "--levels", "two_rooms,hazard_rooms", "--methods",
            "none,shaped,lagrangian", "--seeds", "3", "--constrained-cost", "monitor", "--out",
            str(tmp_path / "b")]  # fmt: skip
    out = benchmark.main(argv)
    assert [c.experiment for c in ran] == ["two_rooms", "hazard_rooms"]
    for cfg in ran:
        assert cfg.quick and cfg.modes == ("none", "shaped", "lagrangian") and cfg.seeds == 3
        assert cfg.constrained_cost == "monitor"
        assert cfg.out == str(tmp_path / "b" / cfg.experiment)
        assert cfg.env_id == EXPERIMENTS[cfg.experiment].env_id
    table = (tmp_path / "b" / "benchmark.md").read_text()
    rows = [line for line in table.splitlines() if line.startswith("| two_rooms")
            or line.startswith("| hazard_rooms")]  # fmt: skip
    assert len(rows) == 6
    assert "lagrangian learn from the monitor's ground-truth cost" in table
    assert "| hazard_rooms | shaped | 30.0 [29.0, 31.0] | 50.0 [49.0, 51.0] |" in table
    assert "n/a" in table  # figures these results do not hold
    summary = json.loads((tmp_path / "b" / "benchmark.json").read_text())
    assert summary["levels"]["two_rooms"]["methods"]["shaped"]["training_violations"][
        "per_seed"] == [11.0] * 3  # fmt: skip
    assert out["table"] == summary
    for level in ("two_rooms", "hazard_rooms"):
        assert (tmp_path / "b" / f"{level}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    ran.clear()
    benchmark.main(argv)  # resumed: both levels are done
    assert ran == []
    benchmark.main([*argv[:5], "none,shaped,lagrangian,checker", *argv[6:]])  # a method more: rerun
    assert [c.experiment for c in ran] == ["two_rooms", "hazard_rooms"]


def test_the_table_names_the_cost_source_only_for_the_methods_it_changes(tmp_path, monkeypatch):
    monkeypatch.setattr(benchmark, "run_experiment", _fake_results)
    argv = ["--quick", "--no-progress", "--levels", "two_rooms", "--seeds", "2", "--out"]
    benchmark.main([*argv, str(tmp_path / "a"), "--methods", "none,shaped"])
    assert "learn from" not in (tmp_path / "a" / "benchmark.md").read_text()
    benchmark.main([*argv, str(tmp_path / "b"), "--methods", "shaped,saute,cpo"])
    table = (tmp_path / "b" / "benchmark.md").read_text()
    assert "saute, cpo learn from the checker's alarms." in table


def test_the_table_shows_the_finished_levels_while_the_rest_are_pending(tmp_path, monkeypatch):
    """An interruption during a level leaves the table, summary and pictures of the levels
    done before it, the others named as pending; the resume completes them."""

    def interrupted(cfg):
        if cfg.experiment == "hazard_rooms":
            raise KeyboardInterrupt
        return _write_results(tmp_path / "b", cfg)

    monkeypatch.setattr(benchmark, "run_experiment", interrupted)
    argv = ["--quick", "--no-progress", "--levels", "two_rooms,hazard_rooms,lava_crossing",
            "--methods", "none,shaped", "--seeds", "2", "--out", str(tmp_path / "b")]  # fmt: skip
    with pytest.raises(KeyboardInterrupt):
        benchmark.main(argv)
    table = (tmp_path / "b" / "benchmark.md").read_text()
    assert "| two_rooms | none |" in table and "| hazard_rooms" not in table
    assert "Not yet run: hazard_rooms, lava_crossing" in table
    summary = json.loads((tmp_path / "b" / "benchmark.json").read_text())
    assert list(summary["levels"]) == ["two_rooms"]
    assert summary["pending"] == ["hazard_rooms", "lava_crossing"]
    assert (tmp_path / "b" / "two_rooms.png").is_file()
    assert not (tmp_path / "b" / "hazard_rooms.png").exists()
    ran = []

    def run(cfg):
        ran.append(cfg.experiment)
        return _write_results(tmp_path / "b", cfg)

    monkeypatch.setattr(benchmark, "run_experiment", run)
    benchmark.main(argv)
    assert ran == ["hazard_rooms", "lava_crossing"]  # two_rooms is read back
    table = (tmp_path / "b" / "benchmark.md").read_text()
    assert "Not yet run" not in table and "| lava_crossing | shaped |" in table
    assert json.loads((tmp_path / "b" / "benchmark.json").read_text())["pending"] == []


def test_a_resume_with_other_seeds_is_refused(tmp_path, monkeypatch):
    monkeypatch.setattr(benchmark, "run_experiment", _fake_results)
    argv = ["--quick", "--no-progress", "--levels", "two_rooms", "--methods", "none",
            "--out", str(tmp_path / "b")]  # fmt: skip
    benchmark.main([*argv, "--seeds", "2"])
    with pytest.raises(ValueError, match="holds a benchmark with --seeds 2"):
        benchmark.main([*argv, "--seeds", "3"])


def test_the_benchmark_levels_include_the_four_scenarios():
    for level in ("two_rooms", "two_rooms_lava", "three_rooms_key", "hazard_rooms"):
        assert level in BENCHMARK_LEVELS
