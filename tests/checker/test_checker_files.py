"""checker.save/load and CheckerDataset.save/load: atomic files, damaged files named."""

import json
import os

import jax
import numpy as np
import pytest

import checker
from checker import CheckerConfig, CheckerDataset
from checker.model import new_checker

SMALL = CheckerConfig(window=2, view_size=3, word_dim=4, gru_dim=4, state_dim=4, cell_dim=2,
                      conv_channels=2, temporal_channels=2, mlp_dim=4, mlp_layers=1)  # fmt: skip


def _dataset(n=6):
    rng = np.random.default_rng(0)
    return CheckerDataset(
        windows=rng.integers(0, 5, (n, 2, 3, 3, 3), dtype=np.uint8),
        tokens=rng.integers(0, 9, (n, 12), dtype=np.int32),
        labels=rng.integers(0, 2, n, dtype=np.uint8),
        template_id=np.arange(n, dtype=np.int32),
        constraint_type=np.ones(n, np.int32),
        scenario=np.array(["TwoRooms-v0"] * n),
        extras={"step": np.arange(n, dtype=np.int32)},
        meta={"env_id": "TwoRooms-v0", "rate": np.float32(0.5), "counts": np.array([1, 2])},
    )


def test_dataset_round_trip_with_numpy_meta(tmp_path):
    ds = _dataset()
    npz, js = ds.save(tmp_path / "sub" / "d")
    assert sorted(os.listdir(tmp_path / "sub")) == ["d.json", "d.npz"]
    back = CheckerDataset.load(js)
    for name in ("windows", "tokens", "labels", "template_id", "constraint_type", "scenario"):
        np.testing.assert_array_equal(getattr(back, name), getattr(ds, name))
    np.testing.assert_array_equal(back.extras["step"], ds.extras["step"])
    assert back.meta == {"env_id": "TwoRooms-v0", "rate": 0.5, "counts": [1, 2]}


def test_dataset_damaged_files_are_named(tmp_path):
    npz, js = _dataset().save(tmp_path / "d")
    data = open(npz, "rb").read()
    open(npz, "wb").write(data[: len(data) // 2])
    with pytest.raises(ValueError, match=r"d\.npz: damaged dataset file"):
        CheckerDataset.load(tmp_path / "d")
    open(js, "w").write('{"vocab": [')
    with pytest.raises(ValueError, match=r"d\.json: damaged or truncated JSON"):
        CheckerDataset.load(tmp_path / "d")


def test_checker_round_trip_and_damaged_files(tmp_path):
    trained = new_checker(SMALL, jax.random.PRNGKey(0), lookahead=2, env_id="TwoRooms-v0",
                          threshold=0.25)  # fmt: skip
    out = tmp_path / "ck"
    checker.save(trained, out)
    assert sorted(os.listdir(out)) == ["config.json", "params.msgpack"]
    assert json.loads((out / "config.json").read_text())["threshold"] == 0.25
    back = checker.load(out)
    assert (back.config, back.lookahead, back.env_id, back.threshold) == (
        SMALL, 2, "TwoRooms-v0", 0.25)  # fmt: skip
    for a, b in zip(jax.tree.leaves(back.params), jax.tree.leaves(trained.params), strict=True):
        np.testing.assert_array_equal(a, b)

    params = (out / "params.msgpack").read_bytes()
    (out / "params.msgpack").write_bytes(params[: len(params) // 2])
    with pytest.raises(ValueError, match=r"params\.msgpack: damaged parameter file"):
        checker.load(out)
    (out / "params.msgpack").write_bytes(params)
    cfg = (out / "config.json").read_text()
    (out / "config.json").write_text(cfg[:-20])
    with pytest.raises(ValueError, match=r"config\.json: damaged or truncated JSON"):
        checker.load(out)
