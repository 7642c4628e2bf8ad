"""``python -m benchmarks.train_speed`` at a tiny size (4 envs x 8 steps, no baseline).

The first test compiles the fused update once (mode checker): about 12 s on 2 idle cores.
The slow-marked tests add ``--profile`` and the baseline.
"""

import json
import math

import pytest

from agents.config import PPOConfig
from benchmarks import train_speed

TINY = [
    "--modes", "checker",
    "--num-envs", "4", "--num-steps", "8", "--epochs", "1", "--minibatches", "2",
    "--timesteps", "64", "--repeats", "2", "--no-baseline",
]  # fmt: skip


def test_tiny_run_prints_one_json_line_per_mode(tmp_path, capsys):
    out = tmp_path / "results" / "speed.json"
    lines = train_speed.main(TINY + ["--out", str(out), "--ops", "4"])
    captured = capsys.readouterr()
    printed = [json.loads(s) for s in captured.out.splitlines()]
    assert printed == lines
    assert [json.loads(s) for s in out.read_text().splitlines()] == lines
    assert [line["mode"] for line in lines] == ["checker"]
    for line in lines:
        assert {"mode", "sps", "compile_s", "device"} <= set(line)
        assert math.isfinite(line["sps"]) and line["sps"] > 0
        assert math.isfinite(line["compile_s"]) and line["compile_s"] > 0
        assert isinstance(line["device"], str) and line["device"]
        assert (line["num_envs"], line["num_steps"], line["epochs"], line["minibatches"]) == (
            4, 8, 1, 2,
        )  # fmt: skip
        # 64 steps over 2 repeats of whole 32-step updates.
        assert line["timesteps"] == 64 and line["updates_per_call"] == 1
        assert len(line["sps_all"]) == 2
        assert "baseline_sps" not in line and "ratio" not in line
    assert "train_speed:" in captured.err  # progress goes to stderr
    assert all(line["network"] == "conv" for line in lines)
    # --ops: the costliest kernels and places of an update, from a profiler trace.
    for line in lines:
        ops = line["ops"]
        assert "error" not in ops, ops
        assert len(ops["ops"]) == len(ops["groups"]) == 4 and ops["traced_ms_per_unit"] > 0
        for rows in (ops["ops"], ops["groups"]):
            ms = [r["ms_per_unit"] for r in rows]
            assert ms == sorted(ms, reverse=True) and ms[-1] >= 0
            assert 0 < sum(r["share"] for r in rows) <= 1.0 + 1e-6
        places = " ".join(r["where"] for r in ops["groups"])
        assert "ActorCritic" in places  # Flax module names reach the profile


@pytest.mark.slow  # the MLP encoder also trains in tests/agents/test_train.py
def test_mlp_flag_times_the_policy_without_convolution(monkeypatch):
    built = []
    real = train_speed.make_config

    def spy(mode, sizes, updates):
        built.append(real(mode, sizes, updates))
        return built[-1]

    monkeypatch.setattr(train_speed, "make_config", spy)
    (line,) = train_speed.main(["--modes", "none", "--mlp"] + TINY[2:])
    assert line["network"] == "mlp" and line["sps"] > 0
    assert built and all(c.conv_channels == () for c in built)


def test_cell_dim_reaches_the_timed_config():
    sizes = {"env": "TwoRooms-v0", "num_envs": 8, "num_steps": 4, "epochs": 1, "minibatches": 2}
    assert train_speed.make_config("none", sizes, 1).cell_dim == PPOConfig().cell_dim
    wide = train_speed.make_config("checker", {**sizes, "cell_dim": 32}, 1)
    assert wide.cell_dim == 32
    # --profile's checker-free reference is built from the timed config's sizes
    assert train_speed.make_config("none", train_speed.sizes_of(wide), 1).cell_dim == 32


def test_cost_source_reaches_the_modes_that_can_use_either():
    sizes = {"env": "TwoRooms-v0", "num_envs": 8, "num_steps": 4, "epochs": 1, "minibatches": 2,
             "cost_source": "monitor"}  # fmt: skip
    for mode in ("lagrangian", "pid_lagrangian", "saute", "cpo", "focops"):
        assert train_speed.make_config(mode, sizes, 1).cost_from == "monitor"
    for mode, own in (("checker", "checker"), ("shield", "checker"), ("none", None)):
        assert train_speed.make_config(mode, sizes, 1).cost_from == own


@pytest.mark.slow  # two more compiles: about a minute on 2 shared cores
def test_the_baselines_are_timed_against_lagrangian():
    argv = ["--modes", "lagrangian", "cpo", "--cost-source", "monitor"] + TINY[2:]
    lines = train_speed.main(argv)
    assert [line["mode"] for line in lines] == ["lagrangian", "cpo"]
    assert lines[0]["time_vs_lagrangian"] == 1.0 and lines[1]["time_vs_lagrangian"] > 0


@pytest.mark.parametrize(
    "argv",
    [
        ["--modes", "bogus"],
        ["--cost-source", "oracle"],
        ["--num-envs", "0"],
        ["--num-envs", "6", "--minibatches", "4"],
        ["--repeats", "-1"],
        ["--ops", "-2"],
        ["--cell-dim", "0"],
        ["--timesteps", "many"],
        ["--env", "NoSuchEnv-v0"],
    ],
)
def test_bad_flags_exit_with_usage(argv, capsys):
    with pytest.raises(SystemExit) as exc:
        train_speed.main(argv)
    assert exc.value.code != 0
    assert "usage:" in capsys.readouterr().err


@pytest.mark.slow  # six more compiles: about a minute on 2 shared cores
def test_profile_breakdown_from_the_public_api():
    (line,) = train_speed.main(["--modes", "checker", "--profile"] + TINY[3:])
    parts = line["breakdown"]
    for key in ("update_s", "rollout_s", "env_step_s", "loss_forward_s"):
        assert math.isfinite(parts[key]) and parts[key] > 0, (key, parts)
    # Differences of medians: finite, possibly < 0 at this tiny size.
    for key in ("optimisation_s", "checker_s", "policy_and_bookkeeping_s",
                "backward_optimizer_gae_shuffle_s"):  # fmt: skip
        assert math.isfinite(parts[key])
    assert set(parts["fractions"]) == {
        "env_step",
        "policy_and_bookkeeping",
        "checker",
        "loss_forward",
        "backward_optimizer_gae_shuffle",
    }
    assert "baseline_breakdown" not in line


def test_help_shows_every_default(capsys):
    with pytest.raises(SystemExit):
        train_speed.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert text.count("(default: ") == 17  # every flag but --help


@pytest.mark.slow  # baseline + profile compiles: 1-2 minutes on 2 shared cores
def test_tiny_run_with_baseline_and_profile():
    pytest.importorskip("navix")
    argv = ["--modes", "checker", "--profile"] + TINY[3:-1]  # sizes of TINY, baseline on
    (line,) = train_speed.main(argv)
    assert line["mode"] == "checker"
    assert line["baseline_sps"] > 0 and line["ratio"] > 0 and len(line["ratio_all"]) == 2
    parts = line["breakdown"]
    assert "error" not in parts, parts
    for key in ("update_s", "rollout_s", "env_step_s", "loss_forward_s"):
        assert math.isfinite(parts[key]) and parts[key] > 0
    assert math.isfinite(parts["checker_s"])  # a difference of two timings: may be < 0
    assert line["baseline_breakdown"]["env_step_s"] > 0


@pytest.mark.parametrize(
    "op_name, where",
    [
        ("jit(run)/while/body/closed_call/transpose(jvp(ActorCritic))/cells/dot_general",
         "backward: ActorCritic/cells"),
        ("jit(run)/while/body/closed_call/jvp(ActorCritic)/jit(relu)/max",
         "loss forward: ActorCritic"),
        ("jit(run)/while/body/closed_call/jit(argsort)/sort", "outside the loss: argsort"),
        ("jit(run)/while/body/Checker.embed_states/cell_conv/conv_general_dilated",
         "outside the loss: Checker.embed_states/cell_conv"),
        ("jit(run)/while/body/add", "outside the loss: (no module)"),
    ],
)  # fmt: skip
def test_op_places_name_the_pass_and_the_module(op_name, where):
    from benchmarks.xla_ops import describe, instruction_sources

    assert describe(op_name) == where
    hlo = f'  %dot.8 = f32[20,8]{{1,0}} dot(%a, %b), metadata={{op_name="{op_name}"}}'
    assert instruction_sources(hlo) == {"dot.8": op_name}


@pytest.mark.slow
def test_baseline_network_times_the_baselines_learner_on_jaxgrid():
    lines = train_speed.main(["--modes", "none", "--baseline-network"] + TINY[2:])
    assert [x["mode"] for x in lines] == ["none", "purejaxrl-jaxgrid"]
    same = lines[1]
    assert same["env"] == "MiniGrid-DoorKey-8x8-v0" and same["sps"] > 0
    assert len(same["sps_all"]) == 2 and "ratio" not in same  # no NAVIX baseline timed


def test_ratio_bound_is_amdahls_law_over_the_env_share():
    assert train_speed.ratio_bound(0.0) == 1.0
    assert train_speed.ratio_bound(0.2) == pytest.approx(1.25)
    with pytest.raises(ValueError, match="env_fraction"):
        train_speed.ratio_bound(1.0)
