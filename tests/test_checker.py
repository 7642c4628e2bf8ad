"""CLI tests of ``python -m checker.train``; the library's tests live in ``tests/checker/``."""

from __future__ import annotations

import json

import pytest

import checker


@pytest.mark.parametrize(
    "flags, name",
    [(["--window", "0"], "--window"), (["--lookahead", "30"], "--lookahead"),
     (["--epochs", "0"], "--epochs"), (["--env", "Nope-v0"], "--env"),
     (["--lr", "-1"], "--lr")],
)  # fmt: skip
def test_cli_rejects_bad_flags(tmp_path, capsys, flags, name):
    from checker.train import main

    with pytest.raises(SystemExit) as exc:
        main(["--out", str(tmp_path / "o"), *flags])
    assert exc.value.code != 0
    assert name in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_cli_end_to_end_small(tmp_path):
    """``python -m checker.train`` on a small budget writes a loadable checker + metrics."""
    from checker.train import main

    out = tmp_path / "ck"
    report = main([
        "--env", "TwoRooms-v0", "--out", str(out), "--samples", "400", "--epochs", "2",
        "--num-envs", "32", "--heldout-samples", "100", "--transfer-samples", "100",
        "--episode-envs", "4", "--episode-steps", "32", "--no-progress",
    ])  # fmt: skip
    back = checker.load(out)
    assert back.env_id == "TwoRooms-v0" and back.lookahead == 1
    saved = json.loads((out / "metrics.json").read_text())
    assert set(saved["metrics"]) == {
        "test", "heldout_language", "full_episodes", "transfer_ThreeRoomsKey-v0",
    }  # fmt: skip
    assert saved["timing_s"]["collect_plus_train"] > 0 and report["samples"] == 400
