"""checker.train.train_checker: the tiny model separates a synthetic toy set."""

from __future__ import annotations

import json

from checker.metrics import evaluate

# --------------------------------------------------------------------------------- training


def test_training_separates_toy_set(toy, trained_toy):
    _, test = toy
    trained, history = trained_toy
    m = evaluate(trained, test)
    assert m["auroc"] > 0.95, m
    assert history["best_epoch"] >= 1 and len(history["train_loss"]) == history["epochs_run"]
    json.dumps(m)  # plain JSON
