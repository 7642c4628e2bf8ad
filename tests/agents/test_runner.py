"""``agents.runner.run``: compiles once, logs, checkpoints and resumes bit-identically,
stops on a non-finite chunk with the last good checkpoint intact, checks the env batch
against the devices before compiling, and shards over several devices with the results of
one; ``load_agents`` and ``experiments.breakdown`` replay a finished run's agents.

Compilations are counted through ``jax.monitoring`` (``helpers.agents_cases.count_compiles``);
``run`` keeps its compiled programs between calls with the same configuration, so the
module's runs of ``TINY`` share one compilation.
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import jax
import numpy as np
import pytest
from helpers.agents_cases import (
    SEEDS,
    TINY,
    assert_counter_sees_compiles,
    count_compiles,
    fast_jit,
    leaves,
)
from helpers.host_devices import ROOT, device_env
from helpers.xla import batch_reset

from agents import checkpoint, runner
from agents.config import PPOConfig
from agents.programs import precompile, programs_for
from agents.runner import NonFiniteError, load_agents, run
from experiments import breakdown

# ------------------------------------------------------------------ multi-device process
# Slow: a fresh process with 4 host devices compiles the sharded programs. When the test is
# selected, the process starts with the module, so that its compilation overlaps the other
# tests; the comparison is the last test.
MULTI_DEVICE_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import jax
    import numpy as np
    from agents.config import PPOConfig
    from agents.runner import run

    config = PPOConfig(**json.loads(sys.argv[1]))
    out = sys.argv[2]
    assert len(jax.devices()) == 4, jax.devices()
    bad = {}
    try:
        run(PPOConfig(**{**json.loads(sys.argv[1]), "num_envs": 6}), progress=False)
    except ValueError as e:
        bad["error"] = str(e)
    result = run(config, seeds=(0, 1), progress=False, out_dir=out + "/run")
    env_leaf = jax.tree.leaves(result["runner"].env)[0]
    np.savez(out + "/params.npz", *[np.asarray(x) for x in jax.tree.leaves(result["params"])])
    json.dump({
        "bad": bad,
        "eval": {k: v.tolist() for k, v in result["eval"].items()},
        "train_violations": result["train_violations"].tolist(),
        "env_devices": len(env_leaf.sharding.device_set),
        "env_shard_shape": list(env_leaf.sharding.shard_shape(env_leaf.shape)),
        "env_shape": list(env_leaf.shape),
    }, open(out + "/result.json", "w"))
    """
)
MULTI_DEVICE_TEST = "test_multi_device_run_matches_single_device"


def _config_json(config: PPOConfig) -> str:
    return json.dumps(dataclasses.asdict(config))


@pytest.fixture(scope="module", autouse=True)
def multi_device_process(request, tmp_path_factory):
    if not any(item.name == MULTI_DEVICE_TEST for item in request.session.items):
        yield None
        return
    out = tmp_path_factory.mktemp("multi_device")
    proc = subprocess.Popen(
        [sys.executable, "-c", MULTI_DEVICE_SCRIPT, _config_json(TINY), str(out)],
        cwd=ROOT, env=device_env(4), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
        text=True,
    )  # fmt: skip
    yield proc, out
    if proc.poll() is None:
        proc.kill()
        proc.communicate()


# ---------------------------------------------------------------------- compiled once
@pytest.fixture(scope="module")
def runs():
    """``run(TINY)`` for one chunk (it compiles the programs), then the whole run.

    The whole run calls the chunk program on its own output for the first time in the
    process: a retrace there (dtype, weak type or sharding drift between the chunk's input
    and output) would compile again, which ``compiles["whole"]`` records.
    """
    compiles = {}
    with count_compiles() as compiles["first"]:
        first = run(TINY, seeds=SEEDS, progress=False, max_chunks=1)
    with count_compiles() as compiles["whole"]:
        whole = run(TINY, seeds=SEEDS, progress=False)
    return first, whole, compiles


@pytest.fixture(scope="module")
def uninterrupted(runs):
    """The reference run of ``TINY`` over ``SEEDS``."""
    return runs[1]


def read_jsonl(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def test_runner_compiles_once(runs):
    """Both chunks of a run share one compiled chunk program, and a second call of ``run``
    with the same configuration compiles nothing."""
    first, whole, compiles = runs
    assert len(compiles["first"]) >= 2  # at least the init and chunk programs
    assert compiles["whole"] == []
    with count_compiles() as compiled:
        again = run(TINY, seeds=SEEDS, progress=False)
    assert compiled == []
    assert again["records"] == whole["records"]
    assert first["records"] == whole["records"][: len(SEEDS)]
    assert again["wall_s"] < first["wall_s"]


def test_precompiled_programs_are_used_and_change_nothing(uninterrupted):
    """Programs compiled ahead of time in another thread (as the experiments do while other
    work runs) are the ones ``run`` uses, final evaluation included, with the results of the
    programs ``run`` compiled itself."""
    thread = threading.Thread(target=precompile, args=(TINY,), kwargs=dict(seeds=SEEDS))
    thread.start()
    thread.join()
    precompile(TINY, seeds=SEEDS, final_episodes=4)  # adds the final evaluation's program
    programs = programs_for(TINY, None, multi_host=False)
    for name, args in (("init", ()), ("chunk", ()), ("final", (4,))):
        assert isinstance(programs.executable(name, len(SEEDS), *args), jax.stages.Compiled)
    with count_compiles() as compiled:
        ahead = run(TINY, seeds=SEEDS, progress=False, final_episodes=4)
    assert not [n for n in compiled if "init" in n or "chunk" in n or "final" in n], compiled
    assert ahead["records"] == uninterrupted["records"]
    for a, b in zip(leaves(ahead["params"]), leaves(uninterrupted["params"]), strict=True):
        np.testing.assert_array_equal(a, b)
    assert set(ahead["final"]) >= {"violation_rate", "success_rate"}


def test_precompile_of_a_finished_run_compiles_only_its_final_evaluation(tmp_path):
    """Resuming a finished run trains nothing, so only its final evaluation is compiled."""
    config = dataclasses.replace(TINY, ent_coef=0.02)  # programs of its own
    assert config.num_chunks == 2
    (tmp_path / checkpoint.DIGESTS).write_text(json.dumps({"1": {}, "2": {}}))
    assert checkpoint.finished(tmp_path, config)
    precompile(config, seeds=SEEDS, final_episodes=4, out_dir=tmp_path)
    programs = programs_for(config, None, multi_host=False)
    assert isinstance(programs.executable("final", len(SEEDS), 4), jax.stages.Compiled)
    for name in ("init", "chunk"):
        assert not isinstance(programs.executable(name, len(SEEDS)), jax.stages.Compiled)


def test_run_result(uninterrupted):
    r = uninterrupted
    assert r["complete"]
    np.testing.assert_array_equal(r["steps"], [2 * TINY.batch_size, 4 * TINY.batch_size])
    for k in ("violation_rate", "mean_reward", "success_rate"):
        assert r["eval"][k].shape == (2, TINY.num_chunks)
    assert len(r["records"]) == 2 * TINY.num_chunks
    assert all(np.all(np.isfinite(x)) for x in leaves(r["params"]))


def test_training_violations_and_costs_are_counted_from_the_first_update(uninterrupted):
    """Every record's cumulative figures sum its agent's chunks from the first; the cost rate
    is that cost over the steps so far (OmniSafe's); TwoRooms' constraints all forbid (no
    budget), so each costly step is a violation."""
    r = uninterrupted
    for i, seed in enumerate(SEEDS):
        mine = sorted((x for x in r["records"] if x["seed"] == seed), key=lambda x: x["chunk"])
        costs = np.cumsum([x["train/env_cost"] for x in mine])
        violations = np.cumsum([x["train/violations"] for x in mine])
        assert [x["train/cum_env_cost"] for x in mine] == costs.tolist()
        assert [x["train/cum_violations"] for x in mine] == violations.tolist()
        assert [x["train/cum_env_cost_rate"] for x in mine] == (costs / r["steps"]).tolist()
        assert [x["train/env_cost"] for x in mine] == [x["train/violations"] for x in mine]
        np.testing.assert_array_equal(r["train_cost_rate"][i], costs / r["steps"])
        assert r["train_env_cost"][i] == costs[-1] and r["train_violations"][i] == violations[-1]
    for k in ("mean_cost", "mean_costly_run", "max_costly_run"):
        assert r["eval"][k].shape == (2, TINY.num_chunks)


def test_chunk_records_sum_each_update_of_the_chunk():
    """A chunk's record sums all its updates, the first included; the early count takes the
    updates of the first 20% of training (TINY: update 0 of 4)."""
    assert runner.early_updates(TINY) == 1
    names = ("episodes", "successes", "episode_return", "violations", "alarms", "blocked",
             "blocked_rate", "cost_rate", "episode_cost", "novelty_rate", "lagrange", "loss",
             "entropy", "approx_kl")  # fmt: skip
    train = {k: np.zeros((1, TINY.eval_every), np.float32) for k in names}
    train["violations"] = np.array([[3, 5]], np.int32)
    train["env_cost"] = np.array([[4.0, 6.0]], np.float32)
    metrics = {"train": train, "eval": {"mean_cost": np.array([0.5], np.float32)}}
    (first,) = runner.chunk_records(TINY, 0, [7], metrics, np.array([8]), None, np.array([10.0]))
    assert first["train/violations"] == 8 and first["train/violations_early"] == 3
    assert first["train/cum_violations"] == 8 and first["eval/mean_cost"] == 0.5
    assert first["train/env_cost"] == 10.0 and first["train/cum_env_cost"] == 10.0
    assert first["train/cum_env_cost_rate"] == 10.0 / (2 * TINY.batch_size)
    (second,) = runner.chunk_records(TINY, 1, [7], metrics, np.array([16]), None,
                                     np.array([20.0]))  # fmt: skip
    assert second["train/violations_early"] == 0 and second["train/cum_violations"] == 16
    assert second["train/cum_env_cost_rate"] == 20.0 / (4 * TINY.batch_size)
    (unknown,) = runner.chunk_records(TINY, 1, [7], metrics, np.array([16]))
    assert unknown["train/cum_env_cost"] is None and unknown["train/cum_env_cost_rate"] is None
    assert unknown["train/env_cost"] == 10.0


def test_a_run_logged_before_the_cost_metrics_resumes(tmp_path, uninterrupted):
    """A run directory whose records predate the cost metrics resumes to the same agents;
    the cumulative cost, unknown, is logged as null and left out of the result."""
    new = ("eval/mean_cost", "eval/mean_costly_run", "eval/max_costly_run", "train/env_cost",
           "train/cum_env_cost", "train/cum_env_cost_rate")  # fmt: skip
    run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, max_chunks=1)
    log = tmp_path / "metrics.jsonl"
    old = [{k: v for k, v in r.items() if k not in new} for r in read_jsonl(log)]
    log.write_text("".join(json.dumps(r) + "\n" for r in old))
    checkpoint.record_digests(checkpoint.make_manager(tmp_path / "checkpoints"), tmp_path)
    done = run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False)
    assert done["complete"]
    for a, b in zip(leaves(done["params"]), leaves(uninterrupted["params"]), strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(done["train_violations"], uninterrupted["train_violations"])
    last = [r for r in done["records"] if r["chunk"] == 1]
    assert all(r["train/cum_env_cost"] is None and "train/env_cost" in r for r in last)
    assert "train_cost_rate" not in done and "train_env_cost" not in done
    assert set(done["eval"]) == {"violation_rate", "mean_reward", "success_rate"}


def test_checkpoint_resume_is_bit_identical(tmp_path, uninterrupted):
    # One compilation serves every call, the resumed (restored) state included.
    with count_compiles() as compiled:
        first = run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, max_chunks=1)
        assert not first["complete"]
        records = read_jsonl(tmp_path / "metrics.jsonl")
        assert sorted((r["seed"], r["chunk"]) for r in records) == [(0, 0), (1, 0)]
        assert (tmp_path / "checkpoints" / "1").is_dir()

        second = run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False)
    assert compiled == []
    assert_counter_sees_compiles()
    assert second["complete"]
    records = read_jsonl(tmp_path / "metrics.jsonl")
    assert sorted((r["seed"], r["chunk"]) for r in records) == [
        (s, c) for s in SEEDS for c in (0, 1)
    ]
    assert records == second["records"]
    for a, b in zip(leaves(second["params"]), leaves(uninterrupted["params"]), strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(leaves(second["runner"]), leaves(uninterrupted["runner"]), strict=True):
        np.testing.assert_array_equal(a, b)
    for k, v in uninterrupted["eval"].items():
        np.testing.assert_array_equal(second["eval"][k], v)
    np.testing.assert_array_equal(second["train_violations"], uninterrupted["train_violations"])
    cum = [r["train/cum_violations"] for r in records if r["seed"] == 0]
    assert cum == sorted(cum)

    # Resuming with other seeds or another configuration is refused ...
    with pytest.raises(ValueError, match="seeds"):
        run(TINY, seeds=(0, 2), out_dir=tmp_path, progress=False)
    with pytest.raises(ValueError, match="lr"):
        run(dataclasses.replace(TINY, lr=5e-4), seeds=SEEDS, out_dir=tmp_path, progress=False)
    # ... and resume=False really starts over (old checkpoints are not resumed later).
    fresh = run(TINY, seeds=(3, 4), out_dir=tmp_path, progress=False, resume=False, max_chunks=1)
    assert not fresh["complete"]
    done = run(TINY, seeds=(3, 4), out_dir=tmp_path, progress=False)
    assert done["complete"]
    assert {r["seed"] for r in read_jsonl(tmp_path / "metrics.jsonl")} == {3, 4}
    assert len(read_jsonl(tmp_path / "metrics.jsonl")) == 4


def test_cancel_stops_between_chunks_and_the_run_resumes_bit_identically(tmp_path, uninterrupted):
    """A set ``cancel`` event stops a run before its next chunk, keeping the checkpoint, and
    the run resumes to the uninterrupted parameters."""
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(runner.Cancelled, match="no checkpoint was written yet"):
        run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, cancel=cancel)
    run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, max_chunks=1)
    with pytest.raises(runner.Cancelled, match=r"before chunk 2; the last good checkpoint"):
        run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, cancel=cancel)
    resumed = run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, cancel=threading.Event())
    assert resumed["complete"]
    for a, b in zip(leaves(resumed["params"]), leaves(uninterrupted["params"]), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.slow
def test_runs_in_two_threads_at_once_match_the_run_alone(uninterrupted):
    """Experiments train two programs at once in threads: neither changes the other's
    numbers (a shaped and an unshaped run, at the same time, against each alone)."""
    shaped = dataclasses.replace(TINY, reward_mode="shaped")
    alone = run(shaped, seeds=SEEDS, progress=False)
    results = {}

    def train(name, config):
        results[name] = run(config, seeds=SEEDS, progress=False)

    threads = [threading.Thread(target=train, args=a) for a in (("none", TINY), ("shaped", shaped))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for name, reference in (("none", uninterrupted), ("shaped", alone)):
        for a, b in zip(leaves(results[name]["runner"]), leaves(reference["runner"]), strict=True):
            np.testing.assert_array_equal(a, b)


def test_checkpoint_written_before_a_runner_field_existed_resumes(tmp_path, uninterrupted, capsys):
    """A checkpoint without ``RunnerState.success`` (written before it existed) resumes, the
    field from zeros, and the run ends as the uninterrupted one."""
    import orbax.checkpoint as ocp

    run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, max_chunks=1)
    manager = checkpoint.make_manager(tmp_path / "checkpoints")
    saved = manager.restore(1)
    assert "success" in saved
    manager.delete(1)
    manager.save(1, args=ocp.args.StandardSave({k: v for k, v in saved.items()
                                                 if k != "success"}))  # fmt: skip
    manager.wait_until_finished()
    checkpoint.record_digests(manager, tmp_path)
    done = run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False)
    assert "predates success" in capsys.readouterr().err
    assert done["complete"]
    for a, b in zip(leaves(done["params"]), leaves(uninterrupted["params"]), strict=True):
        np.testing.assert_array_equal(a, b)


# ------------------------------------------------------------ loading trained agents
@pytest.fixture(scope="module")
def finished(tmp_path_factory, runs):
    """A finished ``run(TINY)`` in a directory (the module's programs, already compiled)."""
    out = tmp_path_factory.mktemp("finished")
    return out, run(TINY, seeds=SEEDS, out_dir=out, progress=False)


def test_agents_load_as_trained_without_changing_the_directory(finished):
    out, result = finished
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    agents = load_agents(out)
    assert agents["complete"] and agents["seeds"] == list(SEEDS)
    assert agents["config"] == dataclasses.replace(TINY, seed=agents["config"].seed)
    for a, b in zip(leaves(agents["params"]), leaves(result["params"]),
                    strict=True):  # fmt: skip
        np.testing.assert_array_equal(a, b)
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before


def test_every_episode_falls_in_one_template_and_one_colour_group(finished, tmp_path):
    out, _ = finished
    cfg = breakdown.BreakdownConfig(run=str(out), episodes=24, out=str(tmp_path / "b.json"))
    result = breakdown.run(cfg)
    assert [r["seed"] for r in result["agents"]] == list(SEEDS)
    for row in result["agents"]:
        for kind in ("template", "colour"):
            groups = {k: g for k, g in row["groups"].items() if k.startswith(kind)}
            assert sum(g["episodes"] for g in groups.values()) == 24
            overall = sum(g["episodes"] * g["violation_rate"] for g in groups.values()) / 24
            assert overall == pytest.approx(row["violation_rate"])
        stages = row["stages"]
        assert list(stages) == ["carried an object", "entered room 2"]  # TwoRooms: one wall
        # the goal lies beyond the wall: no episode reaches it without entering room 2
        assert row["success_rate"] <= stages["entered room 2"] <= 1
    assert (tmp_path / "b.json").exists()


def test_stages_count_the_walls_an_agent_has_passed_and_what_it_carries():
    import jax.numpy as jnp

    import jaxgrid

    env = jaxgrid.make("ThreeRoomsKey-v0")
    names, track = breakdown.stage_tracker(env, jax.random.PRNGKey(0))
    assert names == ["carried an object", "entered room 2", "entered room 3"]
    states, _ = batch_reset(env, jax.random.split(jax.random.PRNGKey(1), 3))
    x = jnp.array([1, env.width // 3 + 1, 2 * env.width // 3 + 1])
    key_held = states.carrying.at[1].set(jnp.array([5, 0, 0], jnp.uint8))
    states = states.replace(agent_pos=states.agent_pos.at[:, 0].set(x), carrying=key_held)
    flags = np.asarray(fast_jit(track)(states))
    assert flags.tolist() == [[False, False, False], [True, True, False], [False, True, True]]
    assert len(breakdown.stage_tracker(jaxgrid.make("TwoRooms-v0"), jax.random.PRNGKey(0))[0]) == 2


def test_groups_name_the_colours_a_sentence_names():
    from jaxgrid.sentences import PAPER

    tokens = PAPER.tokenize_batch(["avoid the red door", "no blue door and no lava",
                                      "avoid the red door"])  # fmt: skip
    masks = breakdown.groups(tokens, np.array([3, 2, 3]))
    assert masks["colour red"].tolist() == [True, False, True]
    assert masks["colour blue"].tolist() == [False, True, False]
    assert masks["template 3: avoid the red door"].tolist() == [True, False, True]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([], "no run.json"),
        (["--run", "/nonexistent"], "no run.json"),
        (["--episodes", "0"], "episodes must be"),
    ],
)
def test_bad_input_is_named(argv, message, finished, capsys):
    out, _ = finished
    argv = argv if "--run" in argv or not argv else ["--run", str(out), *argv]
    with pytest.raises(SystemExit) as e:
        breakdown.main(argv)
    assert e.value.code == 2
    assert message in capsys.readouterr().err


# ------------------------------------------------------------------- non-finite guard
# Every step raises the checker's alarm (threshold 1e-6, far below the tiny checker's
# probabilities); the penalty is 0 for the first chunk
# (penalty_start: half of the 4 updates), then 1e38 per step: the second chunk's returns
# overflow float32. Six envs: one device takes an env batch that 4 devices would refuse.
DIVERGING = dataclasses.replace(
    TINY, num_envs=6, reward_mode="checker", checker_threshold=1e-6, penalty=1e38,
    penalty_start=0.5, penalty_warmup=0.0,
)  # fmt: skip


def test_non_finite_chunk_raises_and_keeps_last_checkpoint(tmp_path, tiny_checker):
    assert DIVERGING.num_updates == 4 and DIVERGING.eval_every == 2
    first = run(DIVERGING, tiny_checker, seeds=SEEDS, out_dir=tmp_path, progress=False,
                max_chunks=1)  # fmt: skip
    assert all(np.all(np.isfinite(x)) for x in leaves(first["params"]))
    checkpoints = tmp_path / "checkpoints"
    with pytest.raises(NonFiniteError, match=r"within updates 3-4 \(seeds \[0, 1\]\)") as e:
        run(DIVERGING, tiny_checker, seeds=SEEDS, out_dir=tmp_path, progress=False)
    assert str(checkpoints) in str(e.value)

    # The last good checkpoint is the only one, untouched: resuming from it (and running no
    # chunk) gives back the state after the first chunk, bit for bit, and its records.
    assert sorted(p.name for p in checkpoints.iterdir()) == ["1"]
    assert sorted((r["seed"], r["chunk"]) for r in read_jsonl(tmp_path / "metrics.jsonl")) == [
        (0, 0), (1, 0)
    ]  # fmt: skip
    kept = run(DIVERGING, tiny_checker, seeds=SEEDS, out_dir=tmp_path, progress=False,
               max_chunks=0)  # fmt: skip
    assert not kept["complete"] and kept["records"] == first["records"]
    for a, b in zip(leaves(kept["runner"]), leaves(first["runner"]), strict=True):
        np.testing.assert_array_equal(a, b)


# ------------------------------------------------------------------------- devices
MESH_SCRIPT = textwrap.dedent(
    """
    import dataclasses, json, sys
    import jax
    from helpers.agents_cases import assert_counter_sees_compiles, count_compiles
    from agents.config import PPOConfig
    from agents.runner import run
    from agents.train import make_learner

    config = PPOConfig(**json.loads(sys.argv[1]))
    assert len(jax.local_devices()) == 4, jax.local_devices()
    # The learner alone is fine on 4 devices; building it puts its sentence table on the
    # device (a trivial compiled transfer), so that what is counted below is run's own.
    make_learner(config)
    with count_compiles() as compiled:
        try:
            run(config, progress=False)
            error = None
        except ValueError as e:
            error = str(e)
    assert_counter_sees_compiles()
    print(json.dumps({"error": error, "compiled": compiled}))
    """
)


def test_mesh_rejects_indivisible_env_batch(tiny_checker):
    """With 4 devices, 6 envs cannot be split: ``run`` raises a ``ValueError`` before it
    compiles anything. One device takes any env batch (6 envs run; nothing to split)."""
    six = dataclasses.replace(TINY, num_envs=6)
    proc = subprocess.run(
        [sys.executable, "-c", MESH_SCRIPT, _config_json(six)],
        cwd=ROOT, env=device_env(4), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-4000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["error"] is not None
    assert "num_envs (6)" in result["error"]
    assert "number of devices (4)" in result["error"]
    assert result["compiled"] == []
    # One device: the same env batch is accepted (DIVERGING has 6 envs; its non-finite
    # updates come later, and no chunk runs here).
    started = run(DIVERGING, tiny_checker, seeds=SEEDS, progress=False, max_chunks=0)
    assert not started["complete"] and started["records"] == []
    assert np.asarray(leaves(started["runner"].env)[0]).shape[:2] == (len(SEEDS), 6)


# ---------------------------------------------------------------- multi-device run
@pytest.mark.slow
def test_multi_device_run_matches_single_device(multi_device_process, uninterrupted):
    proc, out = multi_device_process
    try:
        log, _ = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the 4-device run did not finish in 300 s")
    assert proc.returncode == 0, log[-4000:]
    result = json.loads((out / "result.json").read_text())
    assert "divisible by the number of devices (4)" in result["bad"]["error"]
    # The env batch really is split over the 4 devices (seed axis, then envs).
    assert result["env_devices"] == 4
    assert result["env_shard_shape"][1] * 4 == result["env_shape"][1] == TINY.num_envs
    with np.load(out / "params.npz") as f:
        sharded = [f[f"arr_{i}"] for i in range(len(f.files))]
    single = leaves(uninterrupted["params"])
    assert len(sharded) == len(single)
    for a, b in zip(sharded, single, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    for k, v in uninterrupted["eval"].items():
        np.testing.assert_allclose(result["eval"][k], v, atol=1e-5, err_msg=k)
    np.testing.assert_array_equal(result["train_violations"], uninterrupted["train_violations"])
