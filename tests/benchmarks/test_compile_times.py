"""benchmarks.compile_times: per-id compile seconds, the budget verdict, bad arguments."""

from __future__ import annotations

import json

import pytest

from benchmarks import compile_times as CT


@pytest.mark.slow
def test_reports_each_id_with_its_verdict(tmp_path):
    out = tmp_path / "compile.json"
    ids = ["MiniGrid-Empty-5x5-v0", "MiniGrid-ObstructedMaze-1Dl-v0"]
    report = CT.main(["--ids", *ids, "--num-envs", "4", "--budget", "1e-6", "--json", str(out)])
    assert list(report["ids"]) == ids
    for r in report["ids"].values():
        assert r["reset_s"] > 0 and r["step_s"] > 0 and not r["passed"]  # no compile is free
        assert r["total_s"] == pytest.approx(r["reset_s"] + r["step_s"])
    assert report["failed"] == ids and report["slowest"]["id"] in ids
    assert json.loads(out.read_text())["num_envs"] == 4


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--ids", "MiniGrid-Nope-v0"], "not a native MiniGrid id"),
        (["--num-envs", "0"], "--num-envs must be at least 1"),
        (["--budget", "0"], "--budget must be positive"),
        (["--repeats", "0"], "--repeats must be at least 1"),
    ],
)
def test_bad_arguments_are_refused(argv, message, capsys):
    with pytest.raises(SystemExit):
        CT.main(argv)
    assert message in capsys.readouterr().err


def test_repeats_keep_each_programs_fastest_compile(monkeypatch):
    timings = iter([(3.0, 1.0), (1.0, 4.0)])  # pass 1, pass 2: (reset, step)

    def fake(env_id, num_envs):
        reset_s, step_s = next(timings)
        return {"reset_s": reset_s, "step_s": step_s, "total_s": reset_s + step_s}

    monkeypatch.setattr(CT, "compile_seconds", fake)
    report = CT.main(["--ids", "MiniGrid-Empty-5x5-v0", "--repeats", "2", "--budget", "2.5"])
    r = report["ids"]["MiniGrid-Empty-5x5-v0"]
    assert (r["reset_s"], r["step_s"], r["total_s"]) == (1.0, 1.0, 2.0)
    assert r["passed"] and report["repeats"] == 2 and report["failed"] == []
