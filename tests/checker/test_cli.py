"""The checker's command line, generated from its configs: ``python -m checker`` (every
training setting a flag, ``--counterfactuals`` and ``--distractors`` included), usage errors
naming the flag before anything compiles, and the test and
validation splits that :class:`checker.CheckerTrainConfig` sets for :func:`checker.train_checker`;
``--kind memory`` (its flags, the former ``--label``, its report).
"""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import pytest
from helpers import checker_cases as cases
from helpers.checker_cases import TINY, toy_split
from helpers.cli_help import help_entries, squeezed

import checker
from checker import CheckerTrainConfig, train_checker
from checker import __main__ as checker_main
from checker.train import MemoryTrainConfig


def test_python_m_checker_help_shows_every_setting_with_its_default():
    done = subprocess.run([sys.executable, "-m", "checker", "--help"], capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    entries = help_entries(done.stdout)
    training = {f"--{f.name.replace('_', '-')}" for f in dataclasses.fields(CheckerTrainConfig)}
    oracle = {"--epsilon", "--ignore-prob", "--seek-prob"}
    assert training | oracle | {"--env", "--out", "--samples", "--progress"} <= set(entries)
    assert "--salt" not in entries  # the oracle's salt is --seed
    assert "(required)" in entries["--out"]
    missing = [f for f, text in entries.items() if f not in ("--help", "--out")
               and "(default:" not in text]  # fmt: skip
    assert not missing, missing
    assert "(default:1)" in squeezed(entries["--counterfactuals"])
    assert "(default:0.5)" in squeezed(entries["--distractors"])


def test_flags_set_counterfactuals_distractors_and_every_part(tmp_path):
    run = checker_main.parse(["--out", str(tmp_path), "--counterfactuals", "0", "--distractors",
                              "0.25", "--samples", "1e4", "--seed", "3", "--epsilon", "0.2",
                              "--test-fraction", "0.2", "--val-fraction", "0.1"])  # fmt: skip
    assert (run.train.counterfactuals, run.train.distractors, run.train.seed) == (0, 0.25, 3)
    assert (run.train.test_fraction, run.train.val_fraction) == (0.2, 0.1)
    assert (run.samples, run.oracle.epsilon, run.out) == (10_000, 0.2, str(tmp_path))
    assert run.train == dataclasses.replace(CheckerTrainConfig(), counterfactuals=0,
                                            distractors=0.25, seed=3, test_fraction=0.2,
                                            val_fraction=0.1)  # fmt: skip


@pytest.mark.parametrize(
    "flags, message",
    [(["--window", "0"], "--window must be in [1, 64]"),
     (["--lookahead", "30"], "--lookahead must be in [0, 4 * window]"),
     (["--epochs", "0"], "--epochs must be an integer >= 1"),
     (["--env", "Nope-v0"], "--env: unknown environment id 'Nope-v0'"),
     (["--lr", "-1"], "--lr must be > 0"),
     (["--counterfactuals", "-1"], "--counterfactuals must be an integer >= 0"),
     (["--distractors", "1.5"], "--distractors must be in [0, 1]"),
     (["--seek-prob", "0.9"], "--ignore-prob + seek_prob must be <= 1"),
     (["--test-fraction", "0.5", "--val-fraction", "0.5"],
      "--test-fraction + --val-fraction must be < 1"),
     (["--samples", "-3"], "--samples must be >= 0"),
     (["--batch-size", "2.5"], "'2.5' is not an integer")],
)  # fmt: skip
def test_bad_flags_are_usage_errors_before_anything_runs(tmp_path, capsys, compiles, flags,
                                                         message):  # fmt: skip
    with pytest.raises(SystemExit) as exc:
        checker_main.main(["--out", str(tmp_path / "o"), *flags])
    assert exc.value.code == 2
    err = " ".join(capsys.readouterr().err.replace("│", " ").split())
    assert message in err, err
    assert not (tmp_path / "o").exists() and not compiles


def test_out_is_required(capsys):
    with pytest.raises(SystemExit) as exc:
        checker_main.main([])
    assert exc.value.code == 2 and "--out" in capsys.readouterr().err


def test_train_config_names_the_field_it_rejects():
    for kwargs, field in [({"epochs": 0}, "epochs"), ({"window": 0}, "window"),
                          ({"threshold": 1.0}, "threshold"), ({"seed": -1}, "seed"),
                          ({"val_fraction": 1.0}, "val_fraction"),
                          ({"final_windows": 1}, "final_windows")]:  # fmt: skip
        with pytest.raises(ValueError, match=rf"CheckerTrainConfig\.{field}"):
            CheckerTrainConfig(**kwargs)


def test_train_checker_splits_as_its_config_says():
    """``test_fraction`` and ``val_fraction`` (of the whole set, stratified) become the
    returned test rows and the early-stopping rows; the rest is trained on."""
    data, _ = toy_split()
    settings = CheckerTrainConfig(window=TINY.window, epochs=1, batch_size=64, test_fraction=0.2,
                                  val_fraction=0.1, counterfactuals=0, distractors=0,
                                  threshold=0.4, blocked=0, lava_counterfactuals=False,
                                  final_windows=False)  # fmt: skip
    trained, history, test = train_checker(data, settings, model=TINY, progress=False)
    n, positives = len(data), int(data.labels.sum())
    assert len(test) == history["test_rows"] == pytest.approx(0.2 * n, abs=2)
    assert test.labels.sum() == pytest.approx(0.2 * positives, abs=1)  # stratified
    assert history["val_rows"] == pytest.approx(0.1 * n, abs=2)
    assert history["train_rows"] + history["val_rows"] + len(test) == n
    assert history["epochs_run"] == 1 and trained.threshold == 0.4
    with pytest.raises(ValueError, match=r"CheckerTrainConfig\.window=5"):
        train_checker(data, CheckerTrainConfig(), model=TINY, progress=False)
    with pytest.raises(ValueError, match=r"CheckerTrainConfig\.final_windows=True"):
        train_checker(data, dataclasses.replace(settings, final_windows=True), model=TINY,
                      progress=False)  # fmt: skip


@pytest.mark.slow
def test_python_m_checker_end_to_end_small(tmp_path):
    """``python -m checker`` on a small budget writes a loadable checker + metrics."""
    out = tmp_path / "ck"
    report = checker_main.main([
        "--env", "TwoRooms-v0", "--out", str(out), "--samples", "400", "--epochs", "2",
        "--num-envs", "32", "--heldout-samples", "100", "--transfer-samples", "100",
        "--episode-envs", "4", "--episode-steps", "32", "--no-progress", "--distractors", "0",
    ])  # fmt: skip
    back = checker.load(out)
    assert back.env_id == "TwoRooms-v0" and back.lookahead == 1
    saved = json.loads((out / "metrics.json").read_text())
    assert set(saved["metrics"]) == {
        "test", "heldout_language", "full_episodes", "transfer_ThreeRoomsKey-v0",
    }  # fmt: skip
    assert saved["args"]["train"]["distractors"] == 0
    assert saved["timing_s"]["collect_plus_train"] > 0 and report["samples"] == 400


# ---------------------------------------------------------- python -m checker --kind memory


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--envs", "0"], "--envs must be an int >= 1, got 0"),
        (["--updates", "0"], "--updates must be an int >= 1, got 0"),
        (["--batch-streams", "0"], "--batch-streams must be an int >= 1, got 0"),
        (["--late", "0"], "--late must be at least 1, got 0"),
        (["--envs", "8", "--batch-streams", "16"], "--batch-streams (16) exceeds --envs (8)"),
    ],
)
def test_memory_flags_are_refused_before_any_work(argv, message, capsys):
    with pytest.raises(SystemExit):
        checker_main.main(["--kind", "memory", *argv])
    assert message in capsys.readouterr().err


def test_the_former_label_flag_is_read_as_its_lookahead(capsys):
    """``--label next|into`` (the memory checker's flag before its label timing was named
    ``lookahead``) still works, and says what it means when its value is wrong."""
    parse = lambda *argv: checker_main.parse(["--kind", "memory", *argv])  # noqa: E731
    assert parse().train.lookahead == 1 and parse("--lookahead", "0").train.lookahead == 0
    assert parse("--label", "into").train.lookahead == 0
    assert parse("--label=next", "--envs", "32").train == MemoryTrainConfig(streams=32)
    with pytest.raises(SystemExit) as exc:
        parse("--label", "before")
    assert exc.value.code == 2
    assert "--label must be one of ('next', 'into')" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        checker_main.parse(["--label", "into", "--out", "x"])  # a window checker's flags
    assert "--label" in capsys.readouterr().err


def test_the_kind_chooses_the_flags(capsys):
    assert checker_main.parse(["--out", "x"]).kind == "window"
    assert checker_main.parse(["--kind", "window", "--out", "x"]).kind == "window"
    assert checker_main.parse(["--kind", "memory"]).kind == "memory"
    with pytest.raises(SystemExit) as exc:
        checker_main.parse(["--kind", "lstm"])
    assert exc.value.code == 2 and "invalid choice: 'lstm'" in capsys.readouterr().err


def test_run_reports_settings_and_every_split(monkeypatch):
    monkeypatch.setattr(
        checker_main, "collect_streams", lambda env, key, n, t, guided=0.0: cases.fake_streams(n, t)
    )
    report = checker_main.run_memory(
        num_envs=4,
        num_steps=12,
        config=cases.MEMORY_SMALL,
        train=MemoryTrainConfig(updates=2, batch_streams=2, lookahead=0),
    )
    assert report["train_config"]["lookahead"] == 0
    assert report["train_config"]["updates"] == 2 and report[
        "checker_config"
    ] == dataclasses.asdict(cases.MEMORY_SMALL)
    keys = {"auroc", "positives", "per_type", "late_budget", "costly_budget"}
    assert set(report["train"]) == keys
    assert "heldout" in report and report["wall_s"] > 0
