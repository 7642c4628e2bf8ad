"""The paper-reproduction pipeline: ``--quick`` runs of every experiment, outputs and schema,
resume from finished phases, and bad input rejected before any training."""

from __future__ import annotations

import dataclasses
import json
import os

import pytest

from agents.ppo import PPOConfig
from experiments import pipeline, three_rooms_key, two_rooms, two_rooms_lava
from experiments.report import validate_results

OUTPUTS = ("results.json", "results.md", "curves.png", "checker.json", "episodes.gif",
           "metrics.jsonl", "config.json")  # fmt: skip


def _quick(module, out, *extra):
    """``python -m experiments.<module> --quick --out OUT`` in this process."""
    return pipeline.main(module.DEFAULTS, ["--quick", "--no-progress", "--out", str(out), *extra])


def _check_outputs(out, experiment, modes=pipeline.MODES):
    for name in OUTPUTS:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    results = json.loads((out / "results.json").read_text())
    validate_results(results)
    assert results["experiment"] == experiment
    assert set(results["methods"]) == set(modes)
    for entry in results["methods"].values():
        assert entry["seeds"] == 2
        assert entry["final"]["episodes"] == 2 * 32
        assert len(entry["curve"]) >= 1
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert {r["mode"] for r in records} == set(modes)
    assert (out / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "episodes.gif").read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    return results


@pytest.fixture(scope="module")
def two_rooms_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("two_rooms")
    return out, _quick(two_rooms, out)


def test_two_rooms_quick_outputs(two_rooms_run):
    out, results = two_rooms_run
    on_disk = _check_outputs(out, "two_rooms")
    assert on_disk["methods"]["checker"]["final"] == pytest.approx(
        results["methods"]["checker"]["final"]
    )
    assert (out / "checker" / "config.json").is_file()
    assert (out / "checker_data.npz").is_file()
    assert on_disk["checker"]["heldout"] is not None


def test_two_rooms_rerun_resumes_from_finished_phases(two_rooms_run):
    out, first = two_rooms_run
    stamps = {p: p.stat().st_mtime_ns for p in [out / "checker_data.npz",
                                                  out / "checker" / "params.msgpack"]}  # fmt: skip
    ckpts = sorted(p.name for p in (out / "modes" / "checker" / "checkpoints").iterdir())
    again = _quick(two_rooms, out)
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps  # phases a-c not redone
    assert sorted(p.name for p in (out / "modes" / "checker" / "checkpoints").iterdir()) == ckpts
    for mode in pipeline.MODES:  # same trained agents, same fixed evaluation seeds
        assert again["methods"][mode]["final"] == first["methods"][mode]["final"]
        assert again["methods"][mode]["curve"] == first["methods"][mode]["curve"]


def test_three_rooms_key_quick_reuses_two_rooms_checker(two_rooms_run, tmp_path):
    out, _ = two_rooms_run
    results = _quick(three_rooms_key, tmp_path, "--checker", str(out / "checker"),
                     "--modes", "checker,none")  # fmt: skip
    on_disk = _check_outputs(tmp_path, "three_rooms_key", modes=("checker", "none"))
    assert on_disk["checker"]["transfer"] is not None  # TwoRooms checker on ThreeRoomsKey
    assert results["checker"]["test"] == on_disk["checker"]["test"]
    assert not (tmp_path / "behaviour").exists()  # the checker was reused, not rebuilt


def test_three_rooms_key_preset_explores_and_starts_the_penalty_later():
    """ThreeRooms-Key's agents get the novelty bonus (its own agents, not a TwoRooms behaviour
    agent), 3M steps and the penalty from 40% by default; flags still win; TwoRooms is off."""
    key = three_rooms_key.DEFAULTS.resolved()
    assert (key.steps, key.penalty_start, key.novelty_bonus) == (3_000_000, 0.4, 0.01)
    assert pipeline.phases.ppo_config(key, "none").novelty_bonus == 0.01
    behaviour = pipeline.phases.ppo_config(key, "none", env_id=key.checker_env_id)
    assert behaviour.novelty_bonus == 0.0
    quick = dataclasses.replace(three_rooms_key.DEFAULTS, quick=True).resolved()
    assert (quick.penalty_start, quick.novelty_bonus) == (0.2, 0.01)
    mine = dataclasses.replace(three_rooms_key.DEFAULTS, penalty_start=0.1, novelty_bonus=0.0)
    assert (mine.resolved().penalty_start, mine.resolved().novelty_bonus) == (0.1, 0.0)
    rooms = two_rooms.DEFAULTS.resolved()
    assert (rooms.steps, rooms.penalty_start, rooms.novelty_bonus) == (1_500_000, 0.2, 0.0)


def test_two_rooms_lava_preset_raises_the_entropy_bonus_of_its_agents_only():
    """TwoRooms-Lava's compared agents get ent_coef 0.03 in every preset; its behaviour agent
    (whose rollouts become the checker's data) and the other scenarios keep PPO's 0.01."""
    lava = two_rooms_lava.DEFAULTS.resolved()
    assert lava.ent_coef == 0.03
    for mode in ("checker", "shaped", "none", "lagrangian"):
        assert pipeline.phases.ppo_config(lava, mode).ent_coef == 0.03
    behaviour = pipeline.phases.ppo_config(lava, "none", env_id=lava.checker_env_id)
    assert behaviour.ent_coef == PPOConfig.ent_coef == 0.01
    for preset in ({"quick": True}, {"paper": True}):
        assert dataclasses.replace(two_rooms_lava.DEFAULTS, **preset).resolved().ent_coef == 0.03
    mine = dataclasses.replace(two_rooms_lava.DEFAULTS, ent_coef=0.0).resolved()
    assert pipeline.phases.ppo_config(mine, "checker").ent_coef == 0.0
    for module in (two_rooms, three_rooms_key):
        assert pipeline.phases.ppo_config(module.DEFAULTS.resolved(), "shaped").ent_coef == 0.01


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--bogus"], "unrecognized arguments"),
        (["--seeds", "0"], "--seeds must be a positive integer"),
        (["--modes", "checker,magic"], "unknown mode"),
        (["--quick", "--paper"], "exclude each other"),
        (["--steps", "1.5"], "not an integer"),
        (["--checker", "/nonexistent/checker"], "no trained checker there"),
        (["--lookahead", "99"], "lookahead"),
        (["--novelty-bonus", "-1"], "--novelty-bonus must be >= 0"),
        (["--ent-coef", "-0.5"], "--ent-coef must be >= 0"),
    ],
)
def test_bad_flags_print_usage_and_exit_nonzero(argv, message, capsys):
    with pytest.raises(SystemExit) as exc:
        pipeline.parse_args(argv, two_rooms.DEFAULTS)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "usage:" in err and message in err


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_unwritable_out_fails_before_training(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    with pytest.raises(SystemExit) as exc:
        _quick(two_rooms, locked / "run")
    assert exc.value.code == 2
    assert "not writable" in capsys.readouterr().err


def test_out_that_is_a_file_fails_before_training(tmp_path, capsys):
    target = tmp_path / "a-file"
    target.write_text("not a directory")
    with pytest.raises(SystemExit) as exc:
        _quick(two_rooms, target)
    assert exc.value.code == 2
    assert "not writable" in capsys.readouterr().err
    assert target.read_text() == "not a directory"  # nothing already written is lost


def test_out_of_another_configuration_is_refused(tmp_path, capsys):
    (tmp_path / "config.json").write_text(json.dumps({"experiment": "two_rooms", "seeds": 9}))
    with pytest.raises(SystemExit) as exc:
        _quick(two_rooms, tmp_path)
    assert exc.value.code == 2
    assert "another configuration" in capsys.readouterr().err
