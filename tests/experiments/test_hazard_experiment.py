"""``python -m experiments.hazard_rooms``: the pipeline with a memory checker and a recurrent
policy; its command line, bad input before any compile, and the memory-checker phase."""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest
from helpers.cli_help import help_entries
from helpers.experiment_runs import refused_before_any_compile

import checker
from checker import memory_model as MM
from checker.protocol import NO_ACTION
from checker.train import MemoryTrainConfig
from experiments import checker_phases, hazard_rooms, phases, pipeline, scheduling, two_rooms
from experiments.pipeline import preset
from experiments.report import CHECKER_METRICS
from jaxgrid import language
from jaxgrid.io import write_json

MEMORY_FLAGS = {f"--memory-{n}" for n in ("streams", "steps", "updates", "batch-streams", "lr",
                                          "positive-weight", "guided", "lookahead")}  # fmt: skip
WINDOW_FLAGS = {"--behaviour-steps", "--checker-samples", "--checker-epochs", "--window",
                "--lookahead"}  # fmt: skip


def _help(capsys, scenario) -> dict:
    with pytest.raises(SystemExit) as exc:
        pipeline.parse_args(["--help"], scenario)
    assert exc.value.code == 0
    return help_entries(capsys.readouterr().out)


def test_each_experiment_shows_the_flags_of_its_checker(capsys):
    hazard, window = _help(capsys, hazard_rooms.SCENARIO), _help(capsys, two_rooms.SCENARIO)
    assert MEMORY_FLAGS <= set(hazard) and not WINDOW_FLAGS & set(hazard)
    assert WINDOW_FLAGS <= set(window) and not MEMORY_FLAGS & set(window)
    assert "(default: 0.5)" in hazard["--shield-guided"] and "--shield-guided" not in window
    assert "(default: 600)" in hazard["--memory-updates"]
    assert "--checker-actions" in hazard and "--checker-actions" not in window


def test_the_scenario_is_the_base_with_its_sentences_a_memory_checker_memory_and_novelty():
    cfg = preset(hazard_rooms.SCENARIO)
    assert cfg.checker_kind == "memory" and cfg.ppo.recurrent
    assert dict(cfg.ppo.env_kwargs) == {"sentences": hazard_rooms.SENTENCES}
    base = preset(two_rooms.SCENARIO).ppo
    assert cfg.ppo.novelty_bonus == 0.05 > base.novelty_bonus
    assert cfg.ppo.novelty_claim == 60 and base.novelty_claim == 0
    # the bonus pays for cells here, for (cell, carrying) pairs in the paper's scenarios
    assert not cfg.ppo.novelty_carrying and base.novelty_carrying
    # film codes and alarm-forward, measured with the window checker only, stay off here
    assert base.film_codes and base.alarm_forward
    assert not cfg.ppo.film_codes and not cfg.ppo.alarm_forward
    # Every other PPO setting is the paper scenarios' one.
    same = dataclasses.replace(cfg.ppo, env_id=base.env_id, env_kwargs=(), recurrent=False,
                               novelty_bonus=base.novelty_bonus, novelty_claim=0, film_codes=True,
                               alarm_forward=True, novelty_carrying=True)  # fmt: skip
    assert same == base
    assert cfg.memory_checker.seed == cfg.ppo.seed
    # the shield's own checker learns from streams half of whose actions are the oracle's
    assert cfg.shield_guided == 0.5 and cfg.memory_checker.guided == 0.0
    assert preset(two_rooms.SCENARIO).shield_guided is None
    with pytest.raises(
        ValueError,
        match="shield_guided: the shield's own checker is a memory "
        "checker, and two_rooms trains a window checker",
    ):
        dataclasses.replace(preset(two_rooms.SCENARIO), shield_guided=0.5)
    # its checker learns the step into each frame; the window checkers' just-before label
    assert cfg.memory_checker.lookahead == 0
    assert preset(two_rooms.SCENARIO).memory_checker.lookahead == 1
    with pytest.raises(ValueError, match="ExperimentConfig.checker_kind must be one of"):
        dataclasses.replace(cfg, checker_kind="lstm")
    with pytest.raises(
        ValueError,
        match="checker_actions: only a memory checker reads actions, "
        "and two_rooms trains a window checker",
    ):
        dataclasses.replace(preset(two_rooms.SCENARIO), checker_actions=True)
    with pytest.raises(ValueError, match="ExperimentConfig.checker_actions must be a bool"):
        dataclasses.replace(cfg, checker_actions=1)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--memory-updates", "0"], "--memory-updates must be an int >= 1, got 0"),
        (["--memory-streams", "4"], "--memory-batch-streams (8) exceeds --memory-streams (4)"),
        (["--memory-lr", "0"], "--memory-lr must be > 0"),
        (["--memory-label", "before"], "--memory-label must be one of ('next', 'into')"),
        (["--memory-lookahead", "2"], "--memory-lookahead must be one of (0, 1), got 2"),
        (["--shield-guided", "1.5"], "--shield-guided must be None or a share in [0, 1], got 1.5"),
    ],
)
def test_bad_memory_flags_are_usage_errors_before_any_compile(
    argv, message, tmp_path, capsys, compiles
):
    refused_before_any_compile(hazard_rooms, tmp_path / "run", argv, message, capsys, compiles)


def test_the_former_label_flag_and_record_still_mean_their_lookahead(tmp_path):
    """``--memory-label next|into`` is read as ``--memory-lookahead 1|0``, and a run directory
    whose ``config.json`` records ``memory_checker.label`` resumes with the same lookahead."""
    parse = lambda *argv: pipeline.parse_args([*argv, "--quick"], hazard_rooms.SCENARIO)  # noqa: E731
    assert parse("--memory-label", "next").memory_checker.lookahead == 1
    assert parse("--memory-label=into").memory_checker.lookahead == 0
    cfg = dataclasses.replace(parse(), out=str(tmp_path / "run"))
    phases.prepare_out(cfg)
    path = tmp_path / "run" / "config.json"
    record = json.loads(path.read_text())
    record["memory_checker"] = {**record["memory_checker"], "label": "into"}
    del record["memory_checker"]["lookahead"]
    path.write_text(json.dumps(record))
    phases.prepare_out(cfg)  # resumes
    path.write_text(json.dumps({**record, "memory_checker": {**record["memory_checker"],
                                                             "label": "next"}}))  # fmt: skip
    with pytest.raises(ValueError, match="differs in memory_checker.lookahead"):
        phases.prepare_out(cfg)


def _saved_memory_checker(directory, lookahead=1):
    small = MM.MemoryCheckerConfig(word_dim=8, gru_dim=8, cell_dim=4, conv_channels=4,
                                   state_dim=8, memory_dim=16, mlp_dim=16)  # fmt: skip
    trained = MM.new_memory_checker(small, jax.random.PRNGKey(0), env_id="HazardRooms-v0",
                                    lookahead=lookahead)  # fmt: skip
    checker.save(trained, directory)
    return trained


def test_a_checker_of_the_other_kind_is_refused_by_name(tmp_path):
    _saved_memory_checker(tmp_path / "memory")
    cfg = preset(two_rooms.SCENARIO, "quick")
    cfg = dataclasses.replace(cfg, checker=str(tmp_path / "memory"), out=str(tmp_path / "o"))
    with pytest.raises(ValueError, match="a memory checker, and two_rooms trains its agents "
                                         "with a window checker"):  # fmt: skip
        checker_phases.load_reused(cfg)


def test_a_memory_checker_of_the_other_label_is_refused_by_name(tmp_path):
    """A just-before checker would make HazardRooms' shield block other actions."""
    _saved_memory_checker(tmp_path / "next")
    cfg = preset(hazard_rooms.SCENARIO, "quick")
    cfg = dataclasses.replace(cfg, checker=str(tmp_path / "next"), out=str(tmp_path / "o"))
    with pytest.raises(ValueError, match="trained with lookahead 1, and this run asks for "
                                         "--memory-lookahead 0"):  # fmt: skip
        checker_phases.load_reused(cfg)


def _fake_streams(env, key, n, t, guided=0.0):
    """Streams shaped as :func:`checker.data.collect_streams`'s, without compiling the env."""
    rng = np.random.default_rng(int(jax.random.randint(key, (), 0, 2**31 - 1)))
    starts = np.zeros((n, t), bool)
    starts[:, ::8] = True
    tokens = np.zeros((n, t, language.MAX_LEN), np.int32)
    tokens[..., :2] = 1 + rng.integers(0, 5, (n, t, 1))
    return {
        "frames": rng.integers(0, 6, (n, t, 7, 7, 3)).astype(np.uint8),
        "tokens": tokens, "starts": starts,
        "action": np.where(starts, NO_ACTION, rng.integers(0, NO_ACTION, (n, t))),
        "label": (rng.random((n, t)) < 0.2).astype(np.int32),
        "next_cost": (rng.random((n, t)) < 0.3).astype(np.float32),
        "cost": np.zeros((n, t), np.float32), "violation": np.zeros((n, t), np.int32),
        "ctype": rng.integers(0, len(language.CONSTRAINT_TYPES), (n, t)).astype(np.int32),
        "template": np.zeros((n, t), np.int32), "valid": np.ones((n, t), bool),
    }  # fmt: skip


def test_the_memory_checker_phase_is_skipped_when_done_and_redone_when_damaged(
    tmp_path, capsys, monkeypatch
):
    """A matching checker and report are loaded, not retrained; a report of other parameters
    makes the phase run again (here on a tiny budget of made-up streams), with a message."""
    monkeypatch.setattr(checker_phases, "collect_streams", _fake_streams)
    cfg = dataclasses.replace(
        preset(hazard_rooms.SCENARIO, "quick"), out=str(tmp_path), progress=False,
        memory_checker=MemoryTrainConfig(streams=8, steps=16, updates=2, batch_streams=4),
    )  # fmt: skip
    first, report = checker_phases.memory_checker(cfg, tmp_path)
    assert report["kind"] == "memory" and set(report["test"]) == set(CHECKER_METRICS)
    assert {"per_type", "late_budget", "costly_budget"} <= set(report["details"]["test"])
    again, same = checker_phases.memory_checker(cfg, tmp_path)
    assert same == report and "redoing" not in capsys.readouterr().err
    write_json(tmp_path / "checker.json", {**report, "params_sha256": "0" * 64})
    checker_phases.memory_checker(cfg, tmp_path)
    assert "c. memory checker: redoing this phase" in capsys.readouterr().err


@pytest.mark.slow
def test_the_memory_checker_phase_trains_a_checker_of_actions_when_asked(
    tmp_path, capsys, monkeypatch
):
    """``checker_actions`` gives a checker that reads the action into each frame; a resume
    that asks otherwise retrains it, with a message."""
    monkeypatch.setattr(checker_phases, "collect_streams", _fake_streams)
    cfg = dataclasses.replace(
        preset(hazard_rooms.SCENARIO, "quick"), out=str(tmp_path), progress=False,
        memory_checker=MemoryTrainConfig(streams=8, steps=16, updates=2, batch_streams=4),
        checker_actions=True,
    )  # fmt: skip
    trained, report = checker_phases.memory_checker(cfg, tmp_path)
    assert trained.config.actions and report["training"]["actions"] is True
    plain, _ = checker_phases.memory_checker(
        dataclasses.replace(cfg, checker_actions=False), tmp_path
    )
    assert not plain.config.actions
    assert "reads actions: True, and --checker-actions is False" in capsys.readouterr().err


def test_the_shields_own_checker_is_a_phase_of_its_own(tmp_path, capsys, monkeypatch):
    """``name`` and ``guided`` put a second checker beside the first, trained on other
    streams; a resume with another share of oracle actions retrains it, with a message."""
    shares = []
    monkeypatch.setattr(checker_phases, "collect_streams", lambda env, key, n, t, guided=0.0: (
        shares.append(guided) or _fake_streams(env, key, n, t)))  # fmt: skip
    cfg = dataclasses.replace(
        preset(hazard_rooms.SCENARIO, "quick"), out=str(tmp_path), progress=False,
        memory_checker=MemoryTrainConfig(streams=8, steps=16, updates=2, batch_streams=4),
    )  # fmt: skip
    _, own = checker_phases.memory_checker(cfg, tmp_path, name="shield_checker", guided=0.5)
    assert shares == [0.5, 0.5]  # its training and test streams
    assert own["training"]["guided"] == 0.5 and (tmp_path / "shield_checker.json").exists()
    assert not (tmp_path / "checker.json").exists()
    assert "c'. shield checker: test AUROC" in capsys.readouterr().out
    checker_phases.memory_checker(cfg, tmp_path, name="shield_checker", guided=0.25)
    assert "c'. shield checker: redoing this phase" in capsys.readouterr().err
    assert shares[2:] == [0.25, 0.25]


def test_the_shield_trains_with_its_own_checker_and_the_others_with_the_experiments(
    tmp_path, monkeypatch
):
    """The pipeline's routing, with every phase replaced by a stand-in that records what it
    was given: no training, no compile."""
    made, compiled = {}, {}

    class Stop(Exception):
        pass

    monkeypatch.setattr(pipeline, "make_checker", lambda cfg, out, keep, cancel, reused: (
        "experiment's", {"test": {}}))  # fmt: skip
    monkeypatch.setattr(
        checker_phases,
        "memory_checker",
        lambda cfg, out, name, guided: (
            made.update(name=name, guided=guided) or "shield's",
            {"test": {}, "guided": guided},
        ),
    )
    monkeypatch.setattr(scheduling, "precompile", lambda config, checker, **kw: compiled.update(
        {config.reward_mode: checker}))  # fmt: skip
    monkeypatch.setattr(phases, "train_agents", lambda cfg, out, mode, trained, compiler,
                        cancel: compiler.wait(mode) or {"checker": trained})  # fmt: skip
    monkeypatch.setattr(phases, "write_gif", lambda *a: (_ for _ in ()).throw(Stop()))
    cfg = dataclasses.replace(preset(hazard_rooms.SCENARIO, "quick"), out=str(tmp_path / "o"))
    keep = {}
    with pytest.raises(Stop):
        pipeline.run_experiment(cfg, keep)
    assert made == {"name": checker_phases.SHIELD_CHECKER, "guided": 0.5}
    given = {mode: r["checker"] for mode, r in keep["runs"].items()}
    assert given["shield"] == "shield's" and given["checker"] == given["lagrangian"] == \
        "experiment's"  # fmt: skip
    assert given["none"] is None and given["shaped"] is None  # no checker at all
    assert keep["report"]["shield"] == {"test": {}, "guided": 0.5}
    for mode in ("shield", "checker"):  # compiled with the checker it trains with
        assert compiled.get(mode, given[mode]) == given[mode]
    # without the shield among the modes, its checker is not trained
    made.clear()
    with pytest.raises(Stop):
        pipeline.run_experiment(dataclasses.replace(cfg, modes=("checker",),
                                                    out=str(tmp_path / "p")), {})  # fmt: skip
    assert made == {}


def test_the_breakdown_finds_the_checker_each_mode_trained_with(tmp_path):
    """``experiments.breakdown`` without ``--checker``: the shield's run names the parameters
    of ``shield_checker/``, the other modes' those of ``checker/``."""
    from jax.flatten_util import ravel_pytree

    from checker.store import params_sha256
    from experiments import breakdown

    first = _saved_memory_checker(tmp_path / "checker", lookahead=0)
    own = MM.new_memory_checker(first.config, jax.random.PRNGKey(1), env_id="HazardRooms-v0",
                                lookahead=0)  # fmt: skip
    checker.save(own, tmp_path / "shield_checker")
    for mode, name in (("shield", "shield_checker"), ("checker", "checker")):
        (tmp_path / "modes" / mode).mkdir(parents=True)
        write_json(tmp_path / "modes" / mode / "run.json",
                   {"checker_sha256": params_sha256(tmp_path / name)})  # fmt: skip
        cfg = breakdown.BreakdownConfig(run=str(tmp_path / "modes" / mode))
        found = breakdown.checker_of(cfg)
        expected = own if name == "shield_checker" else first
        np.testing.assert_array_equal(*(ravel_pytree(c.params)[0]
                                        for c in (found, expected)))  # fmt: skip
