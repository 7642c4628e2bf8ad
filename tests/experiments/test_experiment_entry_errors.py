"""The analysis commands (``experiments.shield_judges``, ``false_alarms``, ``breakdown``,
``label_timing``): a user's mistake is one named line and exit status 2 before any long work,
a command with nothing to measure says so, ``breakdown`` names the checkpoint it replayed, and
``label_timing`` locks its ``--out``, checks both arms first and resumes after Ctrl-C."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from helpers.cli_help import exit_code, fake_checker, stderr_text

from experiments import breakdown, false_alarms, label_timing, shield_judges
from jaxgrid import rundir

SCENARIOS = "ThreeRoomsKey-v0, TwoRooms-v0, TwoRoomsLava-v0"


@pytest.mark.parametrize("main", [shield_judges.main, false_alarms.main, breakdown.main,
                                  label_timing.main])  # fmt: skip
def test_help_exits_0(main, capsys):
    assert exit_code(main, ["--help"]) == 0
    assert "--out" in capsys.readouterr().out


# ------------------------------------------------------------ envs and checkers refused
@pytest.mark.parametrize(
    ("env", "instead"),
    [("HazardRooms-v0", "learnt by a memory checker"),
     ("MiniGrid-DoorKey-8x8-v0", "has no constraint, so there is no violation to measure")],
)  # fmt: skip
def test_shield_judges_refuses_an_env_it_cannot_measure(env, instead, capsys, compiles):
    assert exit_code(shield_judges.main, ["--env", env]) == 2
    err = stderr_text(capsys)
    assert f"--env {env}: python -m experiments.shield_judges needs one of the paper's" in err
    assert SCENARIOS in err and instead in err and not compiles


def test_shield_judges_refuses_a_memory_checker(tmp_path, capsys, compiles):
    path = fake_checker(tmp_path / "m", kind="memory")
    assert exit_code(shield_judges.main, ["--checkers", path]) == 2
    assert f"--checkers {path}: a memory checker" in stderr_text(capsys) and not compiles


def test_false_alarms_refuses_an_env_or_checker_it_cannot_score(tmp_path, capsys, compiles):
    window = fake_checker(tmp_path / "w", lookahead=1)
    memory = fake_checker(tmp_path / "m", kind="memory")
    for argv, message in (
        (["--checker", window, "--env-id", "HazardRooms-v0"],
         f"--env-id HazardRooms-v0: python -m experiments.false_alarms needs one of the paper's "
         f"scenarios ({SCENARIOS})"),
        (["--checker", memory], f"--checker {memory}: a memory checker"),
    ):  # fmt: skip
        assert exit_code(false_alarms.main, argv) == 2
        assert message in stderr_text(capsys)
    assert not compiles


@pytest.mark.parametrize("command", ["shield_judges", "false_alarms", "breakdown"])
def test_an_unwritable_out_file_is_refused_before_any_work(command, tmp_path, capsys, compiles):
    a_file = tmp_path / "a-file"
    a_file.write_text("keep")
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text("{}")
    given = {
        "shield_judges": [],
        "breakdown": ["--run", str(run)],
        "false_alarms": ["--checker", fake_checker(tmp_path / "w", lookahead=1)],
    }
    main = {"shield_judges": shield_judges.main, "false_alarms": false_alarms.main,
            "breakdown": breakdown.main}[command]  # fmt: skip
    for out, message in ((a_file / "r.json", "is a file, not a directory"),
                         (tmp_path, "is a directory, not a file")):  # fmt: skip
        assert exit_code(main, [*given[command], "--out", str(out)]) == 2
        assert f"--out {out}" in (err := stderr_text(capsys)) and message in err, err
    assert a_file.read_text() == "keep" and not compiles


@pytest.mark.parametrize("command", ["shield_judges", "false_alarms", "breakdown"])
def test_an_error_past_the_flags_is_one_line_and_status_2(command, tmp_path):
    """A checker directory whose config.json is not a checker's, and a damaged run.json, found
    when the command loads them: one ``error:`` line naming them, no traceback."""
    fake = fake_checker(tmp_path / "w", lookahead=1)  # no vocabulary recorded
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text("{}")
    argv = {"shield_judges": ["--checkers", fake], "false_alarms": ["--checker", fake],
            "breakdown": ["--run", str(run)]}[command]  # fmt: skip
    done = subprocess.run([sys.executable, "-m", f"experiments.{command}", *argv],
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    line = done.stderr.strip().splitlines()[-1]
    assert line.startswith(f"python -m experiments.{command}: error: ")
    named = str(run / "run.json") if command == "breakdown" else "records no constraint vocab"
    assert named in line, line


# ---------------------------------------------------------------------------- breakdown
def test_breakdown_names_an_older_checkpoint_it_replays(tmp_path, capsys):
    (tmp_path / "checkpoints" / "1").mkdir(parents=True)
    (tmp_path / "checkpoints" / "2").mkdir()
    (tmp_path / "checkpoints" / "2.orbax-checkpoint-tmp-7").mkdir()  # not a checkpoint

    class Config:
        num_chunks = 4

    agents = {"chunks": 1, "complete": False, "config": Config}
    got = breakdown.replayed_checkpoint(str(tmp_path), agents)
    assert got == {"chunks": 1, "num_chunks": 4, "complete": False, "newest": False,
                   "newest_chunks": 2}  # fmt: skip
    assert breakdown.replayed_checkpoint(str(tmp_path), {**agents, "chunks": 2})["newest"]
    row = {"seed": 0, "violation_rate": 0.5, "success_rate": 0.25, "groups": {},
           "stages": {}}  # fmt: skip
    (tmp_path / "run.json").write_text("{}")
    breakdown.print_rows(breakdown.BreakdownConfig(run=str(tmp_path), episodes=8), [row], got)
    out = capsys.readouterr().out
    assert "checkpoint after 1 of 4 chunks (unfinished; the newest, after 2 chunks" in out


@pytest.mark.slow
def test_breakdown_records_the_checkpoint_it_replayed(tmp_path):
    """A run whose newest checkpoint is damaged: the older one is replayed, and its output
    JSON says which, and that it is not the newest."""
    from helpers.agents_cases import SEEDS, TINY

    from agents.runner import run

    out = tmp_path / "run"
    run(TINY, seeds=SEEDS, out_dir=out, progress=False)
    newest = max(int(p.name) for p in (out / "checkpoints").iterdir() if p.name.isdigit())
    victim = max((p for p in (out / "checkpoints" / str(newest)).rglob("*") if p.is_file()),
                 key=lambda p: p.stat().st_size)  # fmt: skip
    victim.write_bytes(victim.read_bytes()[:-1] + b"\0")
    result = breakdown.main(["--run", str(out), "--episodes", "8", "--out",
                             str(tmp_path / "b.json")])  # fmt: skip
    saved = json.loads((tmp_path / "b.json").read_text())["checkpoint"]
    assert saved == result["checkpoint"]
    assert saved["chunks"] == newest - 1 and saved["newest_chunks"] == newest
    assert not saved["newest"] and not saved["complete"]


# ------------------------------------------------------------------------- label_timing
@pytest.fixture
def no_training(monkeypatch):
    """``label_timing.run_experiment`` replaced: the arms it was asked to run, none run."""
    calls = []

    def refuse(cfg):
        calls.append(cfg.out)
        raise AssertionError("an arm started")

    monkeypatch.setattr(label_timing, "run_experiment", refuse)
    return calls


def test_label_timing_refuses_a_checker_and_bad_outs_before_any_work(tmp_path, no_training,
                                                                     compiles):  # fmt: skip
    with pytest.raises(ValueError, match="--checker: label_timing trains one checker per"):
        label_timing.main(["--checker", str(tmp_path), "--out", str(tmp_path / "o")])
    a_file = tmp_path / "a-file"
    a_file.write_text("keep")
    with pytest.raises(ValueError, match="not writable"):
        label_timing.main(["--out", str(a_file / "o")])
    with rundir.lock(tmp_path / "held", "holder-under-test"):
        with pytest.raises(rundir.LockHeld, match="holder-under-test"):
            label_timing.main(["--out", str(tmp_path / "held")])
    # the second arm's directory holds a run of other flags: refused before the first trains
    (tmp_path / "o2" / "lookahead0").mkdir(parents=True)
    (tmp_path / "o2" / "lookahead0" / "config.json").write_text('{"seeds": 99}')
    with pytest.raises(ValueError, match="lookahead0 holds a run with another configuration"):
        label_timing.main(["--out", str(tmp_path / "o2"), "--no-progress"])
    assert no_training == [] and a_file.read_text() == "keep" and not compiles
    assert not (tmp_path / "o2" / rundir.LOCK_FILE).exists()


def test_label_timing_ctrl_c_exits_130_and_says_how_to_resume(tmp_path, monkeypatch, capsys):
    def interrupted(cfg):
        raise KeyboardInterrupt

    monkeypatch.setattr(label_timing, "run_experiment", interrupted)
    out = tmp_path / "o"
    assert exit_code(label_timing.main, ["--out", str(out), "--no-progress"]) == 130
    err = stderr_text(capsys)
    assert f"finished phases are kept in {out}; resume with" in err
    assert f"python -m experiments.label_timing --no-progress --out {out}" in err
    assert not (out / rundir.LOCK_FILE).exists()
    assert (out / "lookahead1" / "config.json").exists()  # both arms checked, then recorded
    assert (out / "lookahead0" / "config.json").exists()


@pytest.mark.parametrize("flags, named", [(["--seed", "-1"], "--seed"),
                                          (["--steps", "100"], "--steps")])  # fmt: skip
def test_the_experiments_name_flags_not_internal_settings(flags, named, tmp_path, capsys):
    from experiments import pipeline, two_rooms

    with pytest.raises(SystemExit) as e:
        pipeline.main(two_rooms.SCENARIO, [*flags, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and named in err
    assert "CheckerTrainConfig" not in err and "eval_every" not in err, err
