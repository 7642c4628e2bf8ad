"""checker.metrics against hand computations (AUROC with ties, thresholded metrics, ECE, lead
time), the colour counterfactual on the toy checker, and the memory checker's late-violation
mask and per-type report on hand-made streams."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers import checker_cases as cases

import checker
from checker import CheckerDataset
from checker.metrics import (
    auroc,
    binary_metrics,
    evaluate_streams,
    expected_calibration_error,
    late_violation_mask,
    lead_time,
)

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


@pytest.mark.slow
def test_colour_counterfactual_on_toy(toy, trained_toy):
    """Recolouring the sentence of a detected positive turns it into a (true) negative."""
    _, test = toy
    cf = checker.colour_counterfactual(trained_toy[0], test)
    assert cf["n"] == int(test.labels.sum())
    assert cf["auroc"] > 0.9 and cf["mean_prob"] > cf["mean_prob_counterfactual"]


# ------------------------------------------------------------ the memory checker's streams


def test_late_mask_and_report_read_into_labels_one_frame_later():
    """The hand-made streams below, labelled on the frame after each violating step."""
    d = cases.budget_streams(1, 30)
    d["cost"][0, [3, 13]] = 1  # costly steps lead into frames 3 and 13 ...
    d["label"][0, 13] = 1  # ... and the second was one too many: 10 steps later, not late
    assert not late_violation_mask(d, late=10, lookahead=0).any()
    assert late_violation_mask(d, late=10, lookahead=1).all()  # read as frame 14
    report = evaluate_streams(np.where(d["cost"] > 0, 0.5, 0.0), d, 10, lookahead=0)
    assert report["costly_budget"] == {"auroc": 0.5, "positives": 1}
    report = evaluate_streams(d["label"] * 0.9, d, 10, lookahead=0)
    assert report["costly_budget"]["auroc"] == 1.0 and report["late_budget"]["auroc"] is None


def test_late_mask_and_report_on_hand_made_streams():
    d = cases.budget_streams(2, 30)
    d["starts"][1, 20] = True
    d["cost"][0, 3] = 1  # first costly event at step 3 ...
    d["label"][0, 17] = 1  # ... the violating step 18: 15 steps later
    d["cost"][1, 5] = 1
    d["label"][1, 9] = 1  # violation 5 steps after the first cost
    mask = late_violation_mask(d, late=10)
    assert mask[0].all() and not mask[1].any()
    probs = np.where(d["label"] > 0, 0.9, 0.1)
    report = evaluate_streams(probs, d, late=10)
    assert report["auroc"] == 1.0 and report["per_type"]["budget"]["auroc"] == 1.0
    assert report["per_type"]["avoid"]["auroc"] is None  # no such episodes
    assert report["late_budget"] == {"late": 10, "auroc": 1.0, "positives": 1}
    assert report["costly_budget"]["auroc"] is None  # no costly next step marked
    d["next_cost"][0, [2, 17]] = 1  # a first entry (within budget) and the one too many
    report = evaluate_streams(np.where(d["next_cost"] > 0, 0.5, 0.0), d, late=10)
    assert report["costly_budget"] == {"auroc": 0.5, "positives": 1}  # not counting: a tie
