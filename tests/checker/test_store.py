"""checker.store: save/load round trip (jittable with the checker as an argument) and clear
errors for missing files or another constraint vocabulary."""

from __future__ import annotations

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.xla import CHEAP

import checker
from checker import CheckerDataset, TrainedChecker

# ---------------------------------------------------------------------------- save and load


def test_save_load_roundtrip(tmp_path, toy, trained_toy):
    _, test = toy
    trained, _ = trained_toy
    checker.save(trained, tmp_path / "ck")
    back = checker.load(tmp_path / "ck")
    assert isinstance(back, TrainedChecker)
    assert back.config == trained.config and back.lookahead == trained.lookahead
    w, t = jnp.asarray(test.windows[:64]), jnp.asarray(test.tokens[:64])
    # Jittable with the checker as an argument (params traced, config static).
    logits = jax.jit(TrainedChecker.logits, compiler_options=CHEAP)
    np.testing.assert_array_equal(np.asarray(logits(back, w, t)), np.asarray(logits(trained, w, t)))
    probs = jax.jit(TrainedChecker.probs, compiler_options=CHEAP)(back, w, t)
    np.testing.assert_allclose(np.asarray(probs), jax.nn.sigmoid(logits(trained, w, t)), rtol=1e-6)


def test_missing_files_and_other_vocabulary(tmp_path, episodes, trained_toy):
    with pytest.raises(FileNotFoundError, match="nope"):
        CheckerDataset.load(tmp_path / "nope.npz")
    with pytest.raises(FileNotFoundError, match="nockpt"):
        checker.load(tmp_path / "nockpt")
    episodes[0].save(tmp_path / "d")
    meta = json.loads((tmp_path / "d.json").read_text())
    meta["vocab"] = meta["vocab"] + ["purple_ish"]
    (tmp_path / "d.json").write_text(json.dumps(meta))
    with pytest.raises(ValueError, match="another constraint vocabulary"):
        CheckerDataset.load(tmp_path / "d")
    checker.save(trained_toy[0], tmp_path / "ck")
    cfg = json.loads((tmp_path / "ck" / "config.json").read_text())
    cfg["max_len"] = 20
    (tmp_path / "ck" / "config.json").write_text(json.dumps(cfg))
    with pytest.raises(ValueError, match="another constraint vocabulary"):
        checker.load(tmp_path / "ck")
    os.remove(tmp_path / "ck" / "params.msgpack")
    with pytest.raises(FileNotFoundError, match="params.msgpack"):
        checker.load(tmp_path / "ck")


def test_every_record_names_its_kind_and_a_newer_format_is_refused(tmp_path, trained_toy):
    """A window checker saved today records ``kind`` (one saved before records none and is a
    window checker: ``tests/fixtures/checkers``); an unknown kind or a newer format than this
    code reads is refused by name before anything is loaded."""
    from checker.store import FORMAT_VERSION, checker_kind

    out = tmp_path / "ck"
    checker.save(trained_toy[0], out)
    meta = json.loads((out / "config.json").read_text())
    assert meta["kind"] == "window" and meta["format_version"] == FORMAT_VERSION
    assert checker_kind(out) == "window"
    newer = dict(format_version=FORMAT_VERSION + 1)
    for change, message in ((dict(kind="lstm"), "unknown checker kind 'lstm'"),
                            (newer, "newer than this code")):  # fmt: skip
        (out / "config.json").write_text(json.dumps({**meta, **change}))
        with pytest.raises(ValueError, match=message):
            checker.load(out)
        with pytest.raises(ValueError, match=message):
            checker_kind(out)
