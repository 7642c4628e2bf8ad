"""The pipeline's end-to-end smoke test, and fault injection into its run directory.

One tiny run (``--quick``, one seed, the ``checker`` mode only) is built once for the module by
:func:`experiments.pipeline.run_experiment`; its outputs are checked, then each case copies it,
truncates, bit-flips or deletes one artefact, and resumes the phase that reads it. The phase
must either redo its work, saying so on stderr and leaving artefacts that load again, or stop
with exit status 2 and a message naming the file: never a raw traceback, never a silent success
with other content. The phases are called in this process with the checker object the run was
built with, so their compiled programs are reused. Two processes on one ``--out``: exactly one
works, the other exits with status 2 within 5 seconds.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers.experiment_runs import check_outputs

import checker as chk
from agents.runner import NonFiniteError
from agents.runner import run as run_ppo
from checker.store import params_sha256
from experiments import assembly, checker_phases, phases, pipeline, provenance, two_rooms
from jaxgrid import rundir
from jaxgrid.io import read_json, read_jsonl

ARGV = ["--quick", "--no-progress", "--modes", "checker", "--seeds", "1", "--gif-episodes", "1"]
DAMAGES = ("truncate", "flip", "delete")


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """``(cfg, out, state)`` of a finished tiny run; ``state`` holds what its phases returned."""
    out = tmp_path_factory.mktemp("tiny") / "run"
    cfg = pipeline.parse_args([*ARGV, "--out", str(out)], two_rooms.SCENARIO)
    state = {"out": out}
    state["results"] = pipeline.run_experiment(cfg, keep=state)
    return cfg, out, state


def test_tiny_run_end_to_end(built, capsys):
    """The pipeline's smoke test: every phase ran and every output follows the schema."""
    cfg, out, state = built
    on_disk = check_outputs(out, "two_rooms", modes=("checker",), seeds=1, final_episodes=32)
    assert on_disk == read_json(out / "results.json")
    assert on_disk["methods"]["checker"]["final"] == pytest.approx(
        state["results"]["methods"]["checker"]["final"]
    )
    assert (out / "checker" / "config.json").is_file() and (out / "checker_data.npz").is_file()
    config = read_json(out / "config.json")
    assert config["ppo"]["total_timesteps"] == 16_384 and config["checker_train"]["epochs"] == 3
    test_rows = read_json(out / "checker.json")["details"]["test"]["n"]
    assert test_rows == pytest.approx(0.15 * 512, abs=2)  # the checker config's test split
    code = on_disk["code"]  # one code made every artefact, and it is this one
    assert [e["sha256"] for e in code] == [provenance.code_identity()["sha256"]]
    assert "Warning" not in (out / "results.md").read_text()


def test_resume_with_other_code_is_recorded_and_reported(run_copy, capsys, monkeypatch):
    """A resume after the code changed keeps the finished phases, says so on stderr, and the
    report lists both codes and warns that a fresh run may differ."""
    cfg, out, state = run_copy
    other = {**provenance.code_identity(), "sha256": "0" * 64}
    monkeypatch.setattr(provenance, "code_identity", lambda: other)
    results = pipeline.run_experiment(cfg)
    err = capsys.readouterr().err
    assert "made by other code" in err and "code.json" in err, err
    assert [e["sha256"] for e in results["code"]][1:] == ["0" * 64]
    assert "Warning: 2 versions of the code" in (out / "results.md").read_text()
    assert (
        results["methods"]["checker"]["final"] == state["results"]["methods"]["checker"]["final"]
    )  # the finished phases were kept


@pytest.fixture
def run_copy(built, tmp_path):
    """A fresh copy of the tiny run and its configuration (``--out`` pointing at the copy)."""
    cfg, out, state = built
    copy = tmp_path / "run"
    shutil.copytree(out, copy)
    return pipeline.parse_args([*ARGV, "--out", str(copy)], two_rooms.SCENARIO), copy, state


def cases(params, default):
    """``params`` for ``parametrize``: the ``default`` ones run by default, the rest with
    ``-m slow`` (each redo retrains or recollects; one damage per artefact kind is enough
    for the default run)."""
    return [p if p in default else pytest.param(*p, marks=pytest.mark.slow) for p in params]


def damage(path: Path, how: str) -> Path:
    """Truncate ``path`` to half, flip one bit in its middle, or delete it; for a checkpoint
    directory, its newest step's largest file is damaged (deleted: the whole step)."""
    if path.is_dir():
        step = max((p for p in path.iterdir() if p.name.isdigit()), key=lambda p: int(p.name))
        if how == "delete":
            shutil.rmtree(step)
            return step
        files = [p for p in step.rglob("*") if p.is_file()]
        path = max(files, key=lambda p: p.stat().st_size)
    if how == "delete":
        path.unlink()
    elif how == "truncate":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    else:
        data = bytearray(path.read_bytes())
        # A JSON file's first byte: a flip elsewhere could change a number and stay valid
        # JSON, which no reader can tell without a checksum (parameter files have one).
        at = 0 if path.suffix in (".json", ".jsonl") else len(data) // 2
        data[at] ^= 0x01
        path.write_bytes(bytes(data))
    return path


def assert_redone(capsys, phase: str, name: str) -> None:
    err = capsys.readouterr().err
    assert f"{phase}: redoing this phase" in err, err
    assert name in err, err


def check_recovery(err: str, phase: str, name: str, how: str) -> None:
    """A PPO phase resumes from the older checkpoint when the newest one is deleted (quietly)
    or damaged (saying so); any other damage starts the phase over, saying so."""
    if name == "checkpoints":
        assert "redoing" not in err, err
        if how != "delete":
            assert "damaged or unverified checkpoint" in err and "resuming from an older" in err
    else:
        assert f"{phase}: redoing this phase" in err and name in err, err


def same_tree(a, b) -> bool:
    import jax

    return all(np.array_equal(np.asarray(x), np.asarray(y))
               for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))  # fmt: skip


# ------------------------------------------------------------------ a. behaviour agent
@pytest.mark.parametrize(
    ("name", "how"),
    cases([(n, h) for n in ("metrics.jsonl", "run.json", "checkpoints") for h in DAMAGES],
          default=[("checkpoints", "flip"), ("metrics.jsonl", "truncate")]),
)  # fmt: skip
def test_behaviour_agent_recovers_from_damage(run_copy, capsys, name, how):
    cfg, out, state = run_copy
    damage(out / "behaviour" / name, how)
    _, params = checker_phases.behaviour_agent(cfg, out)
    check_recovery(capsys.readouterr().err, "a. behaviour agent", name, how)
    assert same_tree(params, state["behaviour"][1])  # deterministic: the same agent again
    records = read_jsonl(out / "behaviour" / "metrics.jsonl")
    assert [r["chunk"] for r in records] == list(range(len(records))) and records


# ------------------------------------------------------------------ b. checker data
# Each case collects again (about 40 s here): the sidecar's JSON damage is one case, JSON
# damage of every kind is covered by the other phases' files.
@pytest.mark.parametrize(("name", "how"), cases(
    [("checker_data.npz", how) for how in DAMAGES] + [("checker_data.json", "flip")],
    default=[("checker_data.npz", "flip")]))  # fmt: skip
def test_checker_data_is_collected_again(run_copy, capsys, name, how):
    cfg, out, state = run_copy
    damage(out / name, how)
    data = checker_phases.checker_data(cfg, out, state["behaviour"])
    assert_redone(capsys, "b. checker data", name if how != "delete" else "checker_data")
    assert np.array_equal(data.labels, state["data"].labels)
    assert np.array_equal(data.windows, state["data"].windows)
    assert len(chk.CheckerDataset.load(out / "checker_data")) == len(state["data"])


# ------------------------------------------------------------------ c. checker
@pytest.mark.parametrize(("name", "how"), cases(
    [("checker/params.msgpack", how) for how in DAMAGES]
    + [("checker/config.json", "flip"), ("checker.json", "truncate"), ("checker.json", "delete")],
    default=[("checker/params.msgpack", "flip")]))  # fmt: skip
def test_checker_is_trained_again(run_copy, capsys, name, how):
    cfg, out, state = run_copy
    damage(out / name, how)
    trained, report = checker_phases.train_checker(cfg, out, state["data"], state["behaviour"])
    assert_redone(capsys, "c. checker", Path(name).name)
    assert report["params_sha256"] == params_sha256(out / "checker")
    assert read_json(out / "checker.json")["params_sha256"] == report["params_sha256"]
    assert same_tree(chk.load(out / "checker").params, trained.params)


@pytest.mark.slow  # a retrain; phase c's redo is covered by the damaged-params case
def test_checker_of_other_data_is_trained_again(run_copy, capsys):
    cfg, out, state = run_copy
    other = state["data"].subset(np.arange(len(state["data"]) - 1))
    other.save(out / "checker_data")  # a valid dataset, but not the one the checker saw
    checker_phases.train_checker(cfg, out, other, state["behaviour"])
    assert_redone(capsys, "c. checker", "trained on other data")


# ------------------------------------------------------------------ d. PPO per mode
@pytest.mark.parametrize(
    ("name", "how"),
    cases([(n, h) for n in ("metrics.jsonl", "run.json", "checkpoints") for h in DAMAGES],
          default=[("metrics.jsonl", "truncate"), ("checkpoints", "flip")]),
)  # fmt: skip
def test_mode_recovers_from_damage(run_copy, capsys, name, how):
    cfg, out, state = run_copy
    damage(out / "modes" / "checker" / name, how)
    result = phases.train_agents(cfg, out, "checker", state["trained"])
    check_recovery(capsys.readouterr().err, "d. checker", name, how)
    first = state["runs"]["checker"]
    assert same_tree(result["params"], first["params"])
    assert result["records"] == first["records"]
    assert read_jsonl(out / "modes" / "checker" / "metrics.jsonl") == first["records"]


@pytest.mark.slow  # a new checker is a new compile; phase d's redo is covered above
def test_mode_made_with_another_checker_is_trained_again(run_copy, capsys):
    cfg, out, state = run_copy
    import jax

    other = state["trained"].replace(
        params=jax.tree.map(lambda x: x + 1e-3, state["trained"].params)
    )
    phases.train_agents(cfg, out, "checker", other)
    assert_redone(capsys, "d. checker", "another checker")


# ------------------------------------------------------------------ top-level files
@pytest.mark.parametrize("how", ["truncate", "flip"])
def test_damaged_config_json_stops_with_exit_2_naming_it(run_copy, capsys, how):
    cfg, out, _ = run_copy
    damage(out / "config.json", how)
    with pytest.raises(SystemExit) as e:
        pipeline.main(two_rooms.SCENARIO, [*ARGV, "--out", str(out)])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert str(out / "config.json") in err and "delete it" in err
    assert not (out / rundir.LOCK_FILE).exists()


def test_deleted_config_json_is_written_again(run_copy):
    cfg, out, _ = run_copy
    (out / "config.json").unlink()
    phases.prepare_out(cfg)
    assert read_json(out / "config.json")["seeds"] == 1


@pytest.mark.parametrize("how", DAMAGES)
def test_report_files_are_written_again(run_copy, how):
    cfg, out, state = run_copy
    names = ("results.json", "results.md", "curves.png", "metrics.jsonl", "episodes.gif")
    for name in names:
        damage(out / name, how)
    phases.write_gif(cfg, out, state["runs"], state["trained"])
    assembly.write_outputs(cfg, out, state["results"], state["runs"])
    assert read_json(out / "results.json") == read_json(state["out"] / "results.json")
    assert (out / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "episodes.gif").read_bytes()[:6] in (b"GIF87a", b"GIF89a")
    assert len(read_jsonl(out / "metrics.jsonl")) == len(state["runs"]["checker"]["records"])


# ------------------------------------------------------------------ --checker DIR reuse
def test_reused_checker_with_a_stale_report_is_refused(run_copy, tmp_path, capsys):
    _, out, state = run_copy
    ckpt = out / "checker"
    reuse = pipeline.parse_args([*ARGV, "--out", str(tmp_path / "reuse"), "--checker",
                                 str(ckpt)], two_rooms.SCENARIO)  # fmt: skip
    # it matches: accepted
    _, report = checker_phases.reuse_checker(reuse, checker_phases.load_reused(reuse))
    assert report["test"] == state["report"]["test"]
    # Retrained (here: other parameters) without its report: the report no longer matches.
    import jax

    other = state["trained"].replace(params=jax.tree.map(lambda x: -x, state["trained"].params))
    chk.save(other, ckpt)
    with pytest.raises(SystemExit) as e:
        pipeline.main(two_rooms.SCENARIO, [*ARGV, "--out", str(tmp_path / "r2"), "--checker",
                                           str(ckpt)])  # fmt: skip
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "describe(s) other parameters" in err and "--overwrite" in err


# ------------------------------------------------------------------ runner
@pytest.mark.slow  # compiles another mode; tests/agents/test_runner.py covers the default run
def test_non_finite_error_names_a_checkpoint_only_when_one_exists(built, tmp_path):
    """A penalty of 1e38 from the second chunk on makes the value loss overflow there."""
    cfg = built[0]
    config = dataclasses.replace(phases.ppo_config(cfg, "shaped"), penalty=1e38,
                                 penalty_start=0.5, penalty_warmup=0.0)  # fmt: skip
    assert config.num_chunks == 2
    with pytest.raises(NonFiniteError) as e:
        run_ppo(config, seeds=(0,), out_dir=tmp_path / "a", progress=False)
    assert f"the last good checkpoint (chunk 1) is kept in {tmp_path / 'a' / 'checkpoints'}" \
        in str(e.value)  # fmt: skip
    with pytest.raises(NonFiniteError) as e:
        run_ppo(config, seeds=(0,), out_dir=tmp_path / "b", progress=False, checkpoint_every=2)
    assert "no checkpoint was written yet" in str(e.value)
    assert not list((tmp_path / "b" / "checkpoints").glob("[0-9]*"))


# ------------------------------------------------------------------ one writer
@pytest.mark.slow
def test_two_runs_on_one_out_exactly_one_works(run_copy):
    """A resumes the finished copy (exit 0); B, started while A holds the lock, exits 2
    naming A's pid without compiling anything (JAX logs every compile for it); the lock is
    gone afterwards."""
    _, out, _ = run_copy
    cmd = [sys.executable, "-m", "experiments.two_rooms", *ARGV, "--out", str(out)]
    a = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lock = out / rundir.LOCK_FILE
    deadline = time.monotonic() + 120
    while not (lock.exists() and lock.read_text()) and a.poll() is None:
        assert time.monotonic() < deadline
        time.sleep(0.05)
    assert a.poll() is None, a.communicate()
    t0 = time.monotonic()
    logged = {**os.environ, "JAX_LOG_COMPILES": "1"}
    b = subprocess.run(cmd, capture_output=True, text=True, timeout=120, env=logged)
    wall = time.monotonic() - t0
    a_out, a_err = a.communicate(timeout=600)
    assert a.returncode == 0, a_err
    assert b.returncode == 2, b.stderr
    assert f"pid {a.pid}" in b.stderr and "Traceback" not in b.stderr
    assert "Compiling" not in b.stderr, b.stderr
    assert wall < 30, wall  # a generous bound: its imports take 2-5 s on 2 loaded cores
    assert "redoing" not in a_err and not lock.exists()
    assert json.loads((out / "results.json").read_text())["methods"]["checker"]["seeds"] == 1
    assert os.listdir(out)  # nothing was cleared


# ------------------------------------------------------------------ refuse before work
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--out", ""], "--out: an output directory is required"),
        (["--penalty", "inf"], "--penalty must be finite"),
        (["--lr", "nan"], "--lr must be finite"),
        (["--checker-lr", "inf"], "--checker-lr must be finite"),
        (["--checker-samples", "64"], "--checker-samples 64 leaves 44 windows to train on"),
    ],
)
def test_bad_flags_exit_2_before_any_work(argv, message, tmp_path, capsys, monkeypatch):
    import jax

    events = []
    listen = lambda name, *a, **k: events.append(name)  # noqa: E731
    jax.monitoring.register_event_duration_secs_listener(listen)
    monkeypatch.chdir(tmp_path)
    try:
        with pytest.raises(SystemExit) as e:
            pipeline.main(
                two_rooms.SCENARIO,
                ["--quick", "--no-progress", "--out", str(tmp_path / "run"), *argv],
            )
    finally:
        jax.monitoring.unregister_event_duration_listener(listen)
    assert e.value.code == 2
    assert message in " ".join(capsys.readouterr().err.replace("│", " ").split())
    assert not os.listdir(tmp_path) and not [n for n in events if "compile" in n]
