"""checker.train: the tiny window checker separates a synthetic toy set; augmentations that
would make labels inexact are skipped; training a memory checker lowers its loss."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from helpers import checker_cases as cases
from helpers.checker_cases import TINY

from checker.metrics import evaluate, predict_streams
from checker.train import (
    CheckerTrainConfig,
    MemoryTrainConfig,
    train_checker,
    train_memory_checker,
)
from jaxgrid import language, sentences

# --------------------------------------------------------------------------------- training


def test_training_separates_toy_set(toy, trained_toy):
    _, test = toy
    trained, history = trained_toy
    m = evaluate(trained, test)
    assert m["auroc"] > 0.95, m
    assert history["best_epoch"] >= 1 and len(history["train_loss"]) == history["epochs_run"]
    json.dumps(m)  # plain JSON


def test_blocked_counterfactuals_only_where_labels_stay_exact(toy):
    """``blocked`` adds one negative per training positive; final windows' positives, which
    already entered the cell, get none, and unmarked final windows skip it with a warning."""
    train = toy[0].subset(np.arange(len(toy[0])))
    base = dict(window=TINY.window, epochs=1, batch_size=64, test_fraction=0.0, val_fraction=0.0,
                counterfactuals=0, distractors=0, lava_counterfactuals=False)  # fmt: skip
    rows = {
        b: train_checker(train, CheckerTrainConfig(**base, blocked=b, final_windows=False),
                         model=TINY, progress=False)[1]["train_rows"]
        for b in (0, 1)
    }  # fmt: skip
    assert rows[1] - rows[0] == int(train.labels.sum()) > 0
    train.meta["final_windows"] = True
    settings = CheckerTrainConfig(**base, blocked=1, final_windows=True)
    with pytest.warns(UserWarning, match="no blocked counterfactuals for unmarked final windows"):
        history = train_checker(train, settings, model=TINY, progress=False)[1]
    assert history["train_rows"] == rows[0]
    # Marked final windows: only the positives before their step get a copy.
    train.extras["final"] = np.arange(len(train)) % 3 == 0
    history = train_checker(train, settings, model=TINY, progress=False)[1]
    before = int(np.sum((train.labels > 0) & ~train.extras["final"]))
    assert history["train_rows"] - rows[0] == before > 0
    with pytest.raises(ValueError, match="CheckerTrainConfig.blocked"):
        CheckerTrainConfig(blocked=-1)


def test_lava_counterfactuals_recolour_door_and_lava_positives(toy):
    """``lava_counterfactuals`` adds a recoloured negative per door-and-lava positive facing
    the named door; without it such positives get none."""
    train = toy[0].subset(np.arange(len(toy[0])))
    said = [language.parse(language.detokenize(t)).clauses[0].target.colour for t in train.tokens]
    train.template_id = 7 + 4 * train.template_id  # the same door clause, and "stay away from lava"
    train.tokens = np.stack([sentences.PAPER.tokenize(sentences.render(int(t), c))
                             for t, c in zip(train.template_id, said, strict=True)])  # fmt: skip
    base = dict(window=TINY.window, epochs=1, batch_size=64, test_fraction=0.0, val_fraction=0.0,
                distractors=0, blocked=0, final_windows=False)  # fmt: skip
    rows = {
        lava: train_checker(train, CheckerTrainConfig(**base, lava_counterfactuals=lava),
                            model=TINY, progress=False)[1]["train_rows"]
        for lava in (False, True)
    }  # fmt: skip
    assert rows[False] == len(train)
    assert rows[True] - rows[False] == int(train.labels.sum()) > 0


# ------------------------------------------------------------------- the memory checker


@pytest.mark.parametrize("actions", [pytest.param(False, marks=pytest.mark.slow), True])
def test_training_lowers_the_loss(streams, actions):
    config = dataclasses.replace(cases.MEMORY_SMALL, actions=actions)
    params, losses = train_memory_checker(
        streams, config, MemoryTrainConfig(updates=40, batch_streams=8, lr=3e-3)
    )
    assert losses[-10:].mean() < losses[:5].mean()
    probs = predict_streams(params, config, streams)
    assert probs.shape == streams["label"].shape and ((probs >= 0) & (probs <= 1)).all()


def test_too_many_streams_per_batch_is_refused(streams):
    with pytest.raises(ValueError, match="batch_streams 64 exceeds the 16 streams"):
        train_memory_checker(streams, cases.MEMORY_SMALL, MemoryTrainConfig(batch_streams=64))
