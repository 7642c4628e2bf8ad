"""The paper-reproduction pipeline: its configuration (presets as overrides of one base, the
published sizes, one command line generated from the configs), bad input rejected before any
compile, and (slow) a ``--quick`` TwoRooms run of every mode end to end, resume and checker
reuse. The default run's end-to-end smoke test is in ``test_artifacts.py``."""

from __future__ import annotations

import dataclasses
import json
import os
import re

import pytest
from helpers.cli_help import help_entries, squeezed
from helpers.experiment_runs import check_outputs, quick, refused_before_any_compile

from agents.config import PAPER_MODES, REWARD_MODES, PPOConfig
from checker.train import CheckerTrainConfig
from experiments import (
    checker_phases,
    hazard_rooms,
    label_timing,
    phases,
    pipeline,
    three_rooms_key,
    two_rooms,
    two_rooms_lava,
)
from experiments.pipeline import BASE, ExperimentConfig, preset
from experiments.presets import EXPERIMENTS, PRESETS

SCENARIOS = {"two_rooms": two_rooms, "two_rooms_lava": two_rooms_lava,
             "three_rooms_key": three_rooms_key}  # fmt: skip


def _flat(cfg) -> dict:
    def walk(d, prefix=""):
        for k, v in d.items():
            yield from walk(v, f"{prefix}{k}.") if isinstance(v, dict) else [(prefix + k, v)]

    return dict(walk(dataclasses.asdict(cfg)))


# ------------------------------------------------------------------------- configuration
def test_experiment_config_declares_no_ppo_or_checker_setting_again():
    mine = {f.name for f in dataclasses.fields(ExperimentConfig)}
    for other in (PPOConfig, CheckerTrainConfig):
        assert not mine & {f.name for f in dataclasses.fields(other)}, other


@pytest.mark.parametrize("name", list(PRESETS))
@pytest.mark.parametrize("experiment", list(SCENARIOS))
def test_preset_is_the_base_plus_its_overrides(experiment, name):
    """A preset differs from the base exactly where its row and the preset say, to their
    values (the row's step budget last)."""
    row = SCENARIOS[experiment].SCENARIO
    assert row is EXPERIMENTS[experiment]
    expected = {"experiment": experiment, "ppo.env_id": row.env_id,
                "checker_env_id": row.checker_env_id or row.env_id}  # fmt: skip
    for changes in (row.changes, PRESETS[name], row.budgets.get(name, {})):
        expected.update(_flat_changes(changes))
    got, base = _flat(preset(row, name)), _flat(BASE)
    assert {k for k in got if got[k] != base[k]} == {k for k in expected if expected[k] != base[k]}
    assert {k: got[k] for k in expected} == expected


def test_ppo_defaults_are_the_two_rooms_agents():
    """``PPOConfig(env_id="TwoRooms-v0")`` (docs/training.md) trains the TwoRooms experiment's
    agents: the default preset's run differs in reward mode and evaluation schedule only."""
    for mode in REWARD_MODES:
        run = phases.ppo_config(preset(two_rooms.SCENARIO), mode)
        assert run == PPOConfig(env_id="TwoRooms-v0", reward_mode=mode, eval_every=run.eval_every)


def _flat_changes(changes: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in changes.items():
        out.update(_flat_changes(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
    return out


# The published configurations: (seeds, steps, behaviour steps, checker samples, checker
# epochs, envs, curve points, evaluation episodes, final episodes) of every experiment and
# preset; every other setting is the same for all of them.
R, L, K = "two_rooms", "two_rooms_lava", "three_rooms_key"
QUICK = (2, 16_384, 8_192, 512, 3, 32, 2, 16, 32)
PAPER = (10, 10_000_000, 1_000_000, 12_000, 60, 256, 40, 50, 500)
PUBLISHED = {
    (R, "quick"): QUICK,
    (R, "default"): (5, 1_500_000, 300_000, 12_000, 40, 128, 15, 50, 500),
    (R, "paper"): PAPER,
    (L, "quick"): QUICK,
    (L, "default"): (5, 3_000_000, 600_000, 12_000, 40, 128, 15, 50, 500),
    (L, "paper"): PAPER,
    (K, "quick"): QUICK,
    (K, "default"): (5, 5_000_000, 300_000, 12_000, 40, 128, 15, 50, 500),
    (K, "paper"): PAPER,
}  # fmt: skip


@pytest.mark.parametrize("experiment, name", list(PUBLISHED))
def test_presets_keep_the_published_configurations(experiment, name):
    cfg = preset(SCENARIOS[experiment].SCENARIO, name)
    ppo, chk = cfg.ppo, cfg.checker_train
    got = (cfg.seeds, ppo.total_timesteps, cfg.behaviour_steps, cfg.checker_samples, chk.epochs,
           ppo.num_envs, cfg.curve_points, ppo.eval_episodes, cfg.final_episodes)  # fmt: skip
    assert got == PUBLISHED[experiment, name]
    assert (ppo.num_steps, ppo.num_minibatches, ppo.update_epochs, ppo.lr, ppo.penalty,
            ppo.penalty_start, ppo.penalty_warmup, ppo.ent_coef, ppo.novelty_bonus, ppo.seed,
            cfg.gif_episodes) == (64, 4, 4, 1e-3, 1.0, 0.0, 0.5, 0.01, 0.01, 0, 4)  # fmt: skip
    assert (chk.window, chk.lookahead, chk.test_fraction, chk.val_fraction) == (5, 1, 0.15, 0.15)
    assert cfg.modes == PAPER_MODES and (cfg.quick, cfg.paper) == (name == "quick",
                                                                     name == "paper")  # fmt: skip
    updates = ppo.total_timesteps // ppo.batch_size
    for mode in REWARD_MODES:  # evaluated every max(1, updates // curve_points) updates
        run = phases.ppo_config(cfg, mode)
        assert run.eval_every == max(1, updates // cfg.curve_points) and run.reward_mode == mode
        assert run.num_updates == run.num_chunks * run.eval_every


@pytest.mark.parametrize("name", list(PRESETS))
def test_one_configuration_for_every_scenario(name):
    """Within a preset the scenarios' agents differ in the env id and the step budget only,
    and every behaviour agent is the compared agents' PPO in ``none`` mode."""

    def agents(experiment, mode):
        run = phases.ppo_config(preset(SCENARIOS[experiment].SCENARIO, name), mode)
        return dataclasses.replace(run, env_id="-", total_timesteps=10**9, eval_every=1)

    for mode in REWARD_MODES:
        assert agents(R, mode) == agents(L, mode) == agents(K, mode)
    for experiment in SCENARIOS:
        cfg = preset(SCENARIOS[experiment].SCENARIO, name)
        behaviour = phases.behaviour_config(cfg)
        assert behaviour.env_id == cfg.checker_env_id and behaviour.reward_mode == "none"
        assert dataclasses.replace(behaviour, env_id="-", total_timesteps=10**9,
                                   eval_every=1) == agents(experiment, "none")  # fmt: skip
    key = preset(three_rooms_key.SCENARIO, name)
    assert phases.behaviour_config(key).env_id == "TwoRooms-v0"


def test_flags_set_every_part_and_keep_todays_names(tmp_path):
    argv = ["--seeds", "4", "--steps", "1e6", "--modes", "checker,none", "--quick", "--out",
            str(tmp_path), "--penalty", "2", "--lr", "3e-4", "--ent-coef", "0.05",
            "--penalty-start", "0.3", "--no-progress", "--checker-epochs", "7", "--window", "4",
            "--lookahead", "2", "--seed", "5", "--checker-distractors", "0",
            "--checker-threshold", "0.6"]  # fmt: skip
    cfg = pipeline.parse_args(argv, two_rooms.SCENARIO)
    assert (cfg.seeds, cfg.modes, cfg.quick, cfg.out, cfg.progress) == (
        4,
        ("checker", "none"),
        True,
        str(tmp_path),
        False,
    )
    assert (
        cfg.ppo.total_timesteps,
        cfg.ppo.penalty,
        cfg.ppo.lr,
        cfg.ppo.ent_coef,
        cfg.ppo.penalty_start,
        cfg.ppo.seed,
        cfg.ppo.num_envs,
    ) == (1_000_000, 2.0, 3e-4, 0.05, 0.3, 5, 32)  # --quick's envs stay
    chk = cfg.checker_train
    assert (chk.epochs, chk.window, chk.lookahead, chk.distractors) == (7, 4, 2, 0.0)
    # The checker trains from the first seed, measured at the agents' alarm threshold.
    assert (chk.seed, chk.threshold) == (5, 0.6)


def _help(capsys, argv, scenario, **kw) -> str:
    with pytest.raises(SystemExit) as exc:
        pipeline.parse_args([*argv, "--help"], scenario, **kw)
    assert exc.value.code == 0
    return capsys.readouterr().out


def test_help_groups_the_flags_experiment_ppo_checker(capsys):
    """The experiment's own flags, then PPO's, then the checker's, each under its title."""
    for module in (two_rooms, hazard_rooms):
        text = _help(capsys, [], module.SCENARIO)
        titles = re.findall(r"^\W*((?:experiment |PPO |checker )?options)\W*$", text, re.M)
        assert titles == ["experiment options", "PPO options", "checker options"], titles
        widths = {len(line) for line in text.splitlines() if line.strip() in titles}
        assert len(widths) == 1, widths  # the retitled group is as wide as the others


def test_every_flag_shows_its_default_and_presets_change_them(capsys):
    entries = help_entries(_help(capsys, [], two_rooms.SCENARIO))
    todays = ("out checker modes seeds steps behaviour-steps checker-samples checker-epochs "
              "window lookahead num-envs num-steps num-minibatches update-epochs lr penalty "
              "penalty-start penalty-warmup novelty-bonus ent-coef curve-points eval-episodes "
              "final-episodes gif-episodes seed quick paper progress").split()  # fmt: skip
    checker_training = [
        f"checker-{n}"
        for n in (
            "batch-size",
            "lr",
            "weight-decay",
            "patience",
            "test-fraction",
            "val-fraction",
            "counterfactuals",
            "distractors",
        )
    ]
    assert {f"--{n}" for n in todays + checker_training} <= set(entries)
    hidden = (
        "experiment",
        "checker-env-id",
        "env-id",
        "env-kwargs",
        "reward-mode",
        "eval-every",
        "total-timesteps",
        "checker-seed",
        "checker-threshold-",
    )
    assert not {f"--{n}" for n in hidden} & set(entries)
    missing = [flag for flag, text in entries.items() if flag != "--help" and
               "(default:" not in text]  # fmt: skip
    assert not missing, missing
    assert "(default: 1500000)" in entries["--steps"]
    assert "(default:checker,shaped,none,lagrangian,shield,shield_monitor)" in squeezed(
        entries["--modes"]
    )
    quick_help = help_entries(_help(capsys, ["--quick"], three_rooms_key.SCENARIO))
    assert "(default: 16384)" in quick_help["--steps"]
    assert "(default: 0.01)" in quick_help["--novelty-bonus"]
    timing = help_entries(_help(capsys, [], label_timing.SCENARIO))
    assert "--lookahead" not in timing and "--modes" not in timing and "--window" in timing


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--bogus"], "Unrecognized options: --bogus"),
        (["--seeds", "0"], "--seeds must be an integer >= 1, got 0"),
        (["--modes", "checker,magic"], "--modes: unknown"),
        (["--modes", "shield,shelter"], "--modes: unknown"),
        (["--checker-threshold", "0"], "--checker-threshold must be in (0, 1), got 0.0"),
        (["--checker-threshold", "1.5"], "--checker-threshold must be in (0, 1), got 1.5"),
        (["--quick", "--paper"], "--quick and --paper exclude each other"),
        (["--steps", "1.5"], "'1.5' is not an integer"),
        (["--steps", "1000"], "--steps (1000) gives 0 updates"),
        (["--checker", "/nonexistent/checker"], "--checker /nonexistent/checker: no trained"),
        (["--lookahead", "99"], "--lookahead must be in [0, 4 * window]"),
        (["--novelty-bonus", "-1"], "--novelty-bonus must be >= 0"),
        (["--collect-epsilon", "1.5"], "--collect-epsilon must be a number in [0, 1], got 1.5"),
        (["--ent-coef", "-0.5"], "--ent-coef must be >= 0"),
        (["--num-envs", "30"], "--num-envs (30) must be divisible by num_minibatches"),
        (["--checker-lr", "0"], "--checker-lr must be > 0"),
        (["--checker-test-fraction", "0"], "--checker-test-fraction must be > 0"),
        (["--checker-val-fraction", "0.9"], "--checker-test-fraction + --checker-val-fraction"),
        (["--workers", "0"], "--workers must be an integer >= 1, got 0"),
        (["--constrained-cost", "oracle"], "--constrained-cost must be None or one of"),
        (["--constrained-cost", "monitor", "--modes", "shaped,shield"], "no mode of shaped,shield"),
    ],
)
def test_bad_flags_are_usage_errors_naming_the_flag_before_any_compile(
    argv, message, tmp_path, capsys, compiles
):
    refused_before_any_compile(two_rooms, tmp_path / "run", argv, message, capsys, compiles)


@pytest.mark.skipif(os.geteuid() == 0, reason="root can write anywhere")
def test_unwritable_out_fails_before_training(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    with pytest.raises(SystemExit) as exc:
        quick(two_rooms, locked / "run")
    assert exc.value.code == 2
    assert "not writable" in capsys.readouterr().err


def test_out_that_is_a_file_fails_before_training(tmp_path, capsys):
    target = tmp_path / "a-file"
    target.write_text("not a directory")
    with pytest.raises(SystemExit) as exc:
        quick(two_rooms, target)
    assert exc.value.code == 2
    assert "not writable" in capsys.readouterr().err
    assert target.read_text() == "not a directory"  # nothing already written is lost


def test_out_of_another_configuration_is_refused(tmp_path, capsys):
    (tmp_path / "config.json").write_text(json.dumps({"experiment": "two_rooms", "seeds": 9,
                                                      "ppo": {"lr": 0.5}}))  # fmt: skip
    with pytest.raises(SystemExit) as exc:
        quick(two_rooms, tmp_path)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "another configuration" in err and "ppo.lr" in err and "seeds" in err


def test_out_made_before_an_option_existed_resumes_while_it_is_off(tmp_path):
    """A config.json written before ``ppo.penalty_gate`` existed: the same run while the gate
    is off, another one (named) when it is on."""
    argv = ["--quick", "--no-progress", "--out", str(tmp_path)]
    cfg = pipeline.parse_args(argv, two_rooms.SCENARIO)
    phases.prepare_out(cfg)
    saved = json.loads((tmp_path / "config.json").read_text())
    del saved["ppo"]["penalty_gate"]
    (tmp_path / "config.json").write_text(json.dumps(saved))
    phases.prepare_out(cfg)  # resumes, and records the field from now on
    assert "penalty_gate" in json.loads((tmp_path / "config.json").read_text())["ppo"]
    (tmp_path / "config.json").write_text(json.dumps(saved))
    gated = pipeline.parse_args([*argv, "--penalty-gate", "0.5"], two_rooms.SCENARIO)
    with pytest.raises(ValueError, match="ppo.penalty_gate"):
        phases.prepare_out(gated)


def test_out_recorded_under_a_renamed_setting_resumes(tmp_path):
    """A config.json written when ``ppo.cost_limit`` was named ``ppo.cost_target``: the same
    run with the same value, another one (named) with another."""
    argv = ["--quick", "--no-progress", "--out", str(tmp_path)]
    cfg = pipeline.parse_args(argv, two_rooms.SCENARIO)
    phases.prepare_out(cfg)
    saved = json.loads((tmp_path / "config.json").read_text())
    saved["ppo"]["cost_target"] = saved["ppo"].pop("cost_limit")
    (tmp_path / "config.json").write_text(json.dumps(saved))
    phases.prepare_out(cfg)  # resumes, and records the new name from now on
    assert "cost_target" not in json.loads((tmp_path / "config.json").read_text())["ppo"]
    (tmp_path / "config.json").write_text(json.dumps(saved))
    other = pipeline.parse_args([*argv, "--cost-limit", "0.5"], two_rooms.SCENARIO)
    with pytest.raises(ValueError, match="ppo.cost_limit"):
        phases.prepare_out(other)


def test_out_extends_with_more_modes(tmp_path):
    """Another set of modes is the same run (each mode checks its own directory), and so is
    one without the closing baseline timing; another number of seeds is not."""
    argv = ["--quick", "--no-progress", "--out", str(tmp_path)]
    phases.prepare_out(pipeline.parse_args([*argv, "--modes", "checker"], two_rooms.SCENARIO))
    more = pipeline.parse_args(
        [*argv, "--modes", "checker,shaped,none", "--machine-baseline"], two_rooms.SCENARIO
    )
    phases.prepare_out(more)
    assert json.loads((tmp_path / "config.json").read_text())["modes"] == [
        "checker",
        "shaped",
        "none",
    ]
    with pytest.raises(ValueError, match="seeds"):
        phases.prepare_out(pipeline.parse_args([*argv, "--seeds", "3"], two_rooms.SCENARIO))


# ------------------------------------------------------------------------------ end to end
@pytest.fixture(scope="module")
def two_rooms_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("two_rooms")
    return out, quick(two_rooms, out)


@pytest.mark.slow  # every mode, two seeds; the default run's smoke test is in test_artifacts.py
def test_two_rooms_quick_outputs(two_rooms_run):
    out, results = two_rooms_run
    on_disk = check_outputs(out, "two_rooms")
    assert on_disk["methods"]["checker"]["final"] == pytest.approx(
        results["methods"]["checker"]["final"]
    )
    assert (out / "checker" / "config.json").is_file()
    assert (out / "checker_data.npz").is_file()
    assert on_disk["checker"]["heldout"] is not None
    config = json.loads((out / "config.json").read_text())
    assert config["ppo"]["total_timesteps"] == 16_384 and config["checker_train"]["epochs"] == 3
    checker_report = json.loads((out / "checker.json").read_text())
    test_rows = checker_report["details"]["test"]["n"]
    assert test_rows == pytest.approx(0.15 * 512, abs=2)  # the checker config's test split


@pytest.mark.slow
def test_two_rooms_rerun_resumes_from_finished_phases(two_rooms_run):
    out, first = two_rooms_run
    stamps = {p: p.stat().st_mtime_ns for p in [out / "checker_data.npz",
                                                  out / "checker" / "params.msgpack"]}  # fmt: skip
    ckpts = sorted(p.name for p in (out / "modes" / "checker" / "checkpoints").iterdir())
    again = quick(two_rooms, out)
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps  # phases a-c not redone
    assert sorted(p.name for p in (out / "modes" / "checker" / "checkpoints").iterdir()) == ckpts
    for mode in REWARD_MODES:  # same trained agents, same fixed evaluation seeds
        assert again["methods"][mode]["final"] == first["methods"][mode]["final"]
        assert again["methods"][mode]["curve"] == first["methods"][mode]["curve"]


@pytest.mark.slow
def test_three_rooms_key_quick_reuses_two_rooms_checker(two_rooms_run, tmp_path):
    out, _ = two_rooms_run
    results = quick(three_rooms_key, tmp_path, "--checker", str(out / "checker"),
                    "--modes", "checker,none")  # fmt: skip
    on_disk = check_outputs(tmp_path, "three_rooms_key", modes=("checker", "none"))
    assert on_disk["checker"]["transfer"] is not None  # TwoRooms checker on ThreeRoomsKey
    assert results["checker"]["test"] == on_disk["checker"]["test"]
    assert not (tmp_path / "behaviour").exists()  # the checker was reused, not rebuilt


def test_collection_epsilon_mixes_uniform_actions_into_the_behaviour_agent():
    """``AgentPolicy.epsilon``: 0 acts as the agent (the same program), 1 uniformly at
    random over the 7 actions, whatever the agent prefers."""
    import jax
    import numpy as np
    from helpers.xla import batch_reset

    import jaxgrid
    from agents.train import make_learner

    config = PPOConfig(
        env_id="TwoRooms-v0", num_envs=8, num_steps=8, total_timesteps=64, eval_every=1
    )
    params = jax.jit(make_learner(config).init)(jax.random.key(0)).params
    _, ts = batch_reset(jaxgrid.make("TwoRooms-v0"), jax.random.split(jax.random.key(1), 8))
    obs = jax.tree.map(lambda x: np.repeat(np.asarray(x), 500, axis=0), ts.observation)
    key = jax.random.key(2)
    agent = checker_phases.AgentPolicy(config)
    np.testing.assert_array_equal(
        jax.jit(agent)(params, obs, None, key),
        jax.jit(dataclasses.replace(agent, epsilon=0.0))(params, obs, None, key),
    )
    uniform = dataclasses.replace(agent, epsilon=1.0)
    counts = np.bincount(jax.jit(uniform)(params, obs, None, key), minlength=7)
    assert counts.sum() == 4000 and np.all(np.abs(counts / 4000 - 1 / 7) < 0.03), counts


def test_the_constrained_cost_reaches_the_modes_that_can_learn_from_either_only():
    """--constrained-cost monitor: the constrained modes learn from the monitor's cost, the
    penalty modes and shields keep their own source (their configs are unchanged)."""
    from experiments import phases
    from experiments.pipeline import preset
    from experiments.presets import EXPERIMENTS

    modes = ("checker", "shaped", "lagrangian", "saute", "cpo", "shield")
    base = dataclasses.replace(preset(EXPERIMENTS["two_rooms"], "quick"), modes=modes)
    cfg = dataclasses.replace(base, constrained_cost="monitor")
    for mode in modes:
        config = phases.ppo_config(cfg, mode)
        either = mode in ("lagrangian", "saute", "cpo")
        assert config.cost_source == ("monitor" if either else None)
        assert config.uses_checker == (mode in ("checker", "shield"))
        if not either:
            assert config == phases.ppo_config(base, mode)
    with pytest.raises(ValueError, match="set per mode in an experiment"):
        dataclasses.replace(base, ppo=dataclasses.replace(
            base.ppo, reward_mode="lagrangian", cost_source="monitor"))  # fmt: skip
