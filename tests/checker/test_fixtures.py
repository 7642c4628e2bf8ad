"""Checkers saved by earlier code keep loading and predicting the same numbers, and the same
seeds keep training the same parameters, for both kinds (``tests/fixtures/checkers/``, made
by ``helpers.checker_fixtures``).

* ``window/`` and ``memory/`` were saved by the tiny training runs of each kind; their
  predictions on the recorded inputs (``expected.npz``) must come back bit for bit;
* ``memory_into/`` holds the memory checker's parameters saved with the step-into label
  (``"label": "into"``, read as ``lookahead`` 0);
* rerunning each training run gives the recorded parameter sha256 (``expected.json``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from flax import serialization
from helpers import checker_fixtures as F

import checker
from jaxgrid.rundir import sha256_bytes

EXPECTED = json.loads((F.FIXTURES / "expected.json").read_text())


@pytest.fixture(scope="module")
def recorded():
    with np.load(F.FIXTURES / "expected.npz") as z:
        return {k: z[k] for k in z.files}


def _part(recorded, prefix):
    return {k[len(prefix) :]: v for k, v in recorded.items() if k.startswith(prefix)}


def _sha(trained) -> str:
    return sha256_bytes(serialization.to_bytes(trained.params))


def test_a_saved_window_checker_loads_and_predicts_as_recorded(recorded):
    trained = checker.load(F.FIXTURES / "window")
    assert trained.kind == "window" and trained.lookahead == 1
    assert trained.config == F.WINDOW_MODEL and trained.env_id == "TwoRooms-v0"
    assert _sha(trained) == EXPECTED["params_sha256"]["window"]
    got = F.window_predictions(trained, _part(recorded, "window_in_"))
    for name, value in got.items():
        np.testing.assert_array_equal(value, recorded[f"window_{name}"], err_msg=name)


def test_a_saved_memory_checker_loads_and_predicts_as_recorded(recorded):
    trained = checker.load(F.FIXTURES / "memory")
    assert trained.kind == "memory" and trained.config == F.MEMORY_MODEL
    assert trained.threshold == 0.4 and trained.env_id == "HazardRooms-v0"
    assert _sha(trained) == EXPECTED["params_sha256"]["memory"]
    got = F.memory_predictions(trained, _part(recorded, "memory_in_"))
    for name, value in got.items():
        np.testing.assert_array_equal(value, recorded[f"memory_{name}"], err_msg=name)


def test_the_label_timing_of_saved_memory_checkers_is_read():
    nxt, into = checker.load(F.FIXTURES / "memory"), checker.load(F.FIXTURES / "memory_into")
    assert (nxt.lookahead, into.lookahead) == (1, 0)
    assert _sha(into) == EXPECTED["params_sha256"]["memory"]


@pytest.mark.slow
def test_training_the_window_fixture_again_gives_its_parameters():
    assert _sha(F.train_window()) == EXPECTED["params_sha256"]["window"]


@pytest.mark.slow
def test_training_the_memory_fixture_again_gives_its_parameters():
    assert _sha(F.train_memory()) == EXPECTED["params_sha256"]["memory"]
