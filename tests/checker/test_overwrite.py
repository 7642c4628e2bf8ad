"""A checker directory cannot lie: ``params.msgpack`` and the dataset's npz are checked against
the sha256 in their JSON sidecar; ``python -m checker`` writes only into a new or empty
``--out`` (``--overwrite`` clears an old checker first), locks it, records the parameters'
checksum in ``metrics.json``, and refuses bad flags and combinations before any work."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import jax
import pytest
from helpers.checker_cases import TINY

import checker
from checker import __main__ as checker_main
from checker.model import new_checker
from checker.store import params_sha256
from jaxgrid import rundir


def _flip(path, at: int) -> None:
    data = bytearray(path.read_bytes())
    data[at % len(data)] ^= 0x01
    path.write_bytes(bytes(data))


def _truncate(path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


@pytest.fixture
def saved_checker(tmp_path):
    trained = new_checker(TINY, jax.random.PRNGKey(0), env_id="toy")
    return trained, checker.save(trained, tmp_path / "ckpt")


def test_params_checksum_is_recorded_and_a_good_directory_loads(saved_checker):
    trained, directory = saved_checker
    digest = params_sha256(directory)
    assert digest == rundir.sha256_file(os.path.join(directory, "params.msgpack"))
    loaded = checker.load(directory)
    assert jax.tree.all(jax.tree.map(lambda a, b: bool((a == b).all()), loaded.params,
                                     trained.params))  # fmt: skip


@pytest.mark.parametrize("damage", ["truncate", "flip_middle", "flip_last"])
def test_damaged_params_are_refused_naming_the_file_and_the_fix(saved_checker, damage):
    _, directory = saved_checker
    path = os.path.join(directory, "params.msgpack")
    from pathlib import Path

    p = Path(path)
    if damage == "truncate":
        _truncate(p)
    else:  # a flipped bit in a float: still valid msgpack, so only the checksum can tell
        _flip(p, p.stat().st_size // 2 if damage == "flip_middle" else -1)
    with pytest.raises(ValueError) as e:
        checker.load(directory)
    assert path in str(e.value) and "sha256" in str(e.value) and "--overwrite" in str(e.value)


def test_deleted_params_are_named(saved_checker):
    _, directory = saved_checker
    os.remove(os.path.join(directory, "params.msgpack"))
    with pytest.raises(FileNotFoundError, match="params.msgpack"):
        checker.load(directory)


@pytest.mark.parametrize("damage", ["truncate", "flip", "delete"])
def test_damaged_dataset_npz_is_refused_naming_it(toy, tmp_path, damage):
    npz, js = toy[1].save(tmp_path / "data")
    assert json.loads(open(js).read())["npz_sha256"] == rundir.sha256_file(npz)
    assert len(checker.CheckerDataset.load(tmp_path / "data")) == len(toy[1])
    from pathlib import Path

    p = Path(npz)
    if damage == "truncate":
        _truncate(p)
    elif damage == "flip":
        _flip(p, p.stat().st_size // 2)
    else:
        p.unlink()
    with pytest.raises((ValueError, FileNotFoundError)) as e:
        checker.CheckerDataset.load(tmp_path / "data")
    assert npz in str(e.value)


# ---------------------------------------------------------------- python -m checker
TINY_RUN = ["--samples", "256", "--batch-size", "32", "--epochs", "1", "--num-envs", "16",
            "--heldout-samples", "0", "--transfer-samples", "0", "--episode-steps", "0",
            "--no-progress"]  # fmt: skip


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--samples", "64"], "--samples 64 leaves 44 windows to train on"),
        (["--samples", "64"], "--batch-size 128"),
        (["--penalty", "inf"], None),  # not a flag of python -m checker: a usage error too
        (["--lr", "inf"], "--lr must be finite"),
        (["--weight-decay", "nan"], "--weight-decay must be finite"),
    ],
)
def test_bad_flags_are_refused_before_any_work(argv, message, tmp_path, capsys, compiles):
    out = tmp_path / "ck"
    with pytest.raises(SystemExit) as e:
        checker_main.main(["--out", str(out), *argv])
    assert e.value.code == 2
    if message is not None:
        assert message in " ".join(capsys.readouterr().err.split())
    assert not out.exists() and not compiles


def test_out_that_is_a_file_or_empty_is_refused_before_any_work(tmp_path, capsys, compiles):
    target = tmp_path / "a-file"
    target.write_text("keep")
    for out, message in ((str(target), "is a file"), ("", "an output directory is required")):
        with pytest.raises(SystemExit) as e:
            checker_main.main(["--out", out])
        assert e.value.code == 2
        assert message in capsys.readouterr().err
    assert target.read_text() == "keep" and not compiles


def test_non_empty_out_is_refused_unless_overwrite_and_overwrite_clears_only_a_checker(
    tmp_path, compiles
):
    out = tmp_path / "ck"
    out.mkdir()
    (out / "report.json").write_text("{}")
    with pytest.raises(ValueError, match="not empty.*--overwrite"):
        checker_main.main(["--out", str(out), *TINY_RUN])
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="notes.txt"):
        checker_main.main(["--out", str(out), "--overwrite", *TINY_RUN])
    assert (out / "notes.txt").read_text() == "mine" and (out / "report.json").exists()
    assert not (out / rundir.LOCK_FILE).exists() and not compiles


def test_a_locked_out_is_refused_naming_the_holder(tmp_path, compiles):
    with rundir.lock(tmp_path / "ck", "holder-under-test"):
        with pytest.raises(rundir.LockHeld, match="holder-under-test"):
            checker_main.main(["--out", str(tmp_path / "ck"), *TINY_RUN])
    assert not compiles


def test_second_process_on_a_locked_out_exits_2_within_5_s(tmp_path):
    out = tmp_path / "ck"
    with rundir.lock(out, "holder-under-test"):
        t0 = time.monotonic()
        done = subprocess.run([sys.executable, "-m", "checker", "--out", str(out), *TINY_RUN],
                              capture_output=True, text=True, timeout=60)  # fmt: skip
        wall = time.monotonic() - t0
    assert done.returncode == 2, done.stderr
    assert f"pid {os.getpid()}" in done.stderr and "holder-under-test" in done.stderr
    assert wall < 5, wall


def test_overwrite_retrains_and_no_stale_report_survives(tmp_path, saved_checker):
    """A directory with an old checker and an old report.json: --overwrite removes them, the
    new metrics.json names the new parameters, and --checker reuse would accept it."""
    _, old = saved_checker
    with open(os.path.join(old, "report.json"), "w") as f:
        json.dump({"test": {"auroc": 0.99}, "params_sha256": params_sha256(old)}, f)
    old_digest = params_sha256(old)
    report = checker_main.main(["--out", old, "--overwrite", *TINY_RUN])
    assert sorted(os.listdir(old)) == ["config.json", "metrics.json", "params.msgpack"]
    digest = params_sha256(old)
    assert digest != old_digest
    on_disk = json.loads(open(os.path.join(old, "metrics.json")).read())
    assert on_disk["params_sha256"] == report["params_sha256"] == digest
    checker.load(old)
