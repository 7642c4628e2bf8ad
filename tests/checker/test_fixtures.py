"""Checkers saved by earlier code keep loading and predicting the same numbers, and the same
seeds keep training the same parameters, for both kinds (``tests/fixtures/checkers/``, made
by ``helpers.checker_fixtures``).

* ``window/`` and ``memory/`` were saved by the tiny training runs of each kind: their
  parameters must load bit for bit, and their predictions on the recorded inputs
  (``expected.npz``) must come back with the same alarms and the same numbers to float32
  rounding;
* ``memory_into/`` holds the memory checker's parameters saved with the step-into label
  (``"label": "into"``, read as ``lookahead`` 0);
* rerunning each training run gives the saved parameters to float32 rounding (on the
  machine that recorded them, bit for bit: the sha256 in ``expected.json``).

XLA:CPU's float results depend on the processor it compiles for in the last bits (an AMD
EPYC and the recording machine, same jax 0.10.2, differ by up to 3e-6 relative in the
predictions and 1.5e-6 absolute in retrained parameters), so floats are compared to
``RTOL``/``ATOL``, far below what any change of model, data or training would move.
"""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest
from flax import serialization
from helpers import checker_fixtures as F

import checker
from jaxgrid.rundir import sha256_bytes

EXPECTED = json.loads((F.FIXTURES / "expected.json").read_text())
RTOL, ATOL = 1e-5, 1e-7  # predictions: float32 rounding across processors
PARAMS_ATOL = 1e-5  # retrained parameters (|p| <= 1.3): rounding accumulated over training


@pytest.fixture(scope="module")
def recorded():
    with np.load(F.FIXTURES / "expected.npz") as z:
        return {k: z[k] for k in z.files}


def _part(recorded, prefix):
    return {k[len(prefix) :]: v for k, v in recorded.items() if k.startswith(prefix)}


def _sha(trained) -> str:
    return sha256_bytes(serialization.to_bytes(trained.params))


def _assert_predicts_as_recorded(got: dict, recorded: dict, kind: str, threshold: float):
    for name, value in got.items():
        want = recorded[f"{kind}_{name}"]
        np.testing.assert_allclose(value, want, rtol=RTOL, atol=ATOL, err_msg=name)
    alarms = np.asarray(got["probs"]) > threshold
    np.testing.assert_array_equal(alarms, recorded[f"{kind}_probs"] > threshold, err_msg="alarms")


def _assert_same_parameters(trained, kind: str):
    saved = checker.load(F.FIXTURES / kind)
    if _sha(trained) == EXPECTED["params_sha256"][kind]:
        return  # the recording machine's processor: bit for bit
    for got, want in zip(jax.tree.leaves(trained.params), jax.tree.leaves(saved.params),
                         strict=True):  # fmt: skip
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=0, atol=PARAMS_ATOL)


def test_a_saved_window_checker_loads_and_predicts_as_recorded(recorded):
    trained = checker.load(F.FIXTURES / "window")
    assert trained.kind == "window" and trained.lookahead == 1
    assert trained.config == F.WINDOW_MODEL and trained.env_id == "TwoRooms-v0"
    assert _sha(trained) == EXPECTED["params_sha256"]["window"]
    got = F.window_predictions(trained, _part(recorded, "window_in_"))
    _assert_predicts_as_recorded(got, recorded, "window", trained.threshold)


def test_a_saved_memory_checker_loads_and_predicts_as_recorded(recorded):
    trained = checker.load(F.FIXTURES / "memory")
    assert trained.kind == "memory" and trained.config == F.MEMORY_MODEL
    assert trained.threshold == 0.4 and trained.env_id == "HazardRooms-v0"
    assert _sha(trained) == EXPECTED["params_sha256"]["memory"]
    got = F.memory_predictions(trained, _part(recorded, "memory_in_"))
    _assert_predicts_as_recorded(got, recorded, "memory", trained.threshold)


def test_the_label_timing_of_saved_memory_checkers_is_read():
    nxt, into = checker.load(F.FIXTURES / "memory"), checker.load(F.FIXTURES / "memory_into")
    assert (nxt.lookahead, into.lookahead) == (1, 0)
    assert _sha(into) == EXPECTED["params_sha256"]["memory"]


@pytest.mark.slow
def test_training_the_window_fixture_again_gives_its_parameters():
    _assert_same_parameters(F.train_window(), "window")


@pytest.mark.slow
def test_training_the_memory_fixture_again_gives_its_parameters():
    _assert_same_parameters(F.train_memory(), "memory")
