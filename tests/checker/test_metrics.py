"""checker.metrics against hand computations (AUROC with ties, thresholded metrics, ECE, lead
time) and the colour counterfactual on the toy checker."""

from __future__ import annotations

import json

import numpy as np
import pytest

import checker
from checker import CheckerDataset
from checker.metrics import auroc, binary_metrics, expected_calibration_error, lead_time

# ---------------------------------------------------------------------------------- metrics


def test_auroc_with_ties_by_hand():
    # Pairs (pos, neg): (.8,.8) tie = 1/2, (.8,.1) = 1, (.3,.8) = 0, (.3,.1) = 1 -> 2.5 / 4.
    assert auroc([1, 0, 1, 0], [0.8, 0.8, 0.3, 0.1]) == pytest.approx(0.625)
    assert auroc([1, 1, 0], [0.5, 0.5, 0.5]) == pytest.approx(0.5)
    assert auroc([0, 1], [0.1, 0.9]) == 1.0 and auroc([1, 0], [0.1, 0.9]) == 0.0
    assert auroc([1, 1], [0.1, 0.2]) is None


def test_binary_metrics_and_ece_by_hand():
    y = [1, 1, 1, 0, 0, 0]
    p = [0.9, 0.6, 0.2, 0.7, 0.1, 0.0]
    m = binary_metrics(y, p, 0.5)
    # tp=2 (0.9, 0.6), fn=1, fp=1 (0.7), tn=2
    assert (m["tp"], m["fn"], m["fp"], m["tn"]) == (2, 1, 1, 2)
    assert m["accuracy"] == pytest.approx(4 / 6)
    assert m["precision"] == pytest.approx(2 / 3) and m["recall"] == pytest.approx(2 / 3)
    assert m["f1"] == pytest.approx(2 / 3)
    # ECE: bins [0.9] acc 1 conf .9; [.6] 1 vs .6; [.2] 1 vs .2; [.7] 0 vs .7; [.1] 0 vs .1;
    # [0.0] 0 vs 0 -> (0.1 + 0.4 + 0.8 + 0.7 + 0.1 + 0) / 6
    assert expected_calibration_error(y, p) == pytest.approx(2.1 / 6)
    none = binary_metrics([0, 0], [0.1, 0.2])
    assert none["precision"] is None and none["auroc"] is None
    json.dumps(none)


def test_lead_time_by_hand():
    # Episode 1: steps 0..4, violation on step 4 (next_violation at step 3); first alarm at 2.
    # Episode 2: no violation, alarm at step 1 -> a false alarm. Episode 3: violation on step 2,
    # no alarm -> missed. Episode 4: incomplete -> ignored.
    ep = [1] * 5 + [2] * 3 + [3] * 3 + [4] * 2
    step = [0, 1, 2, 3, 4, 0, 1, 2, 0, 1, 2, 0, 1]
    nxt = [0, 0, 0, 1, 0, 0, 0, 0, 0, 1, 0, 0, 0]
    complete = [True] * 11 + [False] * 2
    probs = [0.1, 0.2, 0.7, 0.9, 0.1, 0.0, 0.6, 0.1, 0.1, 0.2, 0.1, 0.9, 0.9]
    n = len(ep)
    ds = CheckerDataset(
        windows=np.zeros((n, 1, 5, 5, 3), np.uint8), tokens=np.zeros((n, 13), np.int32),
        labels=np.asarray(nxt, np.uint8), template_id=np.zeros(n, np.int32),
        constraint_type=np.zeros(n, np.int32), scenario=np.full(n, "x"),
        extras={"episode": np.asarray(ep), "step": np.asarray(step),
                "next_violation": np.asarray(nxt, np.uint8), "complete": np.asarray(complete)},
    )  # fmt: skip
    lt = lead_time(ds, probs, 0.5)
    assert lt["episodes"] == 3 and lt["violating_episodes"] == 2 and lt["clean_episodes"] == 1
    assert lt["mean_lead_time"] == 2.0 and lt["lead_time_histogram"] == {"2": 1}
    assert lt["detected"] == 0.5 and lt["detected_before"] == 0.5
    assert lt["false_alarm_rate"] == 1.0 and lt["false_alarm_window_rate"] == pytest.approx(1 / 3)


def test_colour_counterfactual_on_toy(toy, trained_toy):
    """Recolouring the sentence of a detected positive turns it into a (true) negative."""
    _, test = toy
    cf = checker.colour_counterfactual(trained_toy[0], test)
    assert cf["n"] == int(test.labels.sum())
    assert cf["auroc"] > 0.9 and cf["mean_prob"] > cf["mean_prob_counterfactual"]
