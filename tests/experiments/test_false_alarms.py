"""experiments.false_alarms: counts per cell in front that add up to the totals, door labels
by state and named colour, and clear errors for bad input."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from helpers.checker_cases import TINY

import checker as chk
import jaxgrid
from checker.model import new_checker
from experiments import false_alarms
from jaxgrid.constants import BLUE, CLOSED, DOOR, EMPTY, KEY, LOCKED, OPEN, RED


def test_front_groups_name_doors_by_state_and_sentence():
    front = np.array([[DOOR, RED, OPEN], [DOOR, BLUE, OPEN], [DOOR, RED, LOCKED], [KEY, RED, 0],
                      [EMPTY, 0, 0], [DOOR, BLUE, CLOSED]], np.uint8)  # fmt: skip
    named = np.array([RED, RED, BLUE, RED, -1, -1])
    got = false_alarms.front_groups(front, named).tolist()
    assert got == ["door open named", "door open other", "door locked other", "key", "empty",
                   "door closed other"]  # fmt: skip


@pytest.mark.slow
def test_counts_add_up(tmp_path):
    """An untrained checker with its threshold at the median score of the same windows."""
    untrained = new_checker(TINY, jax.random.PRNGKey(0), env_id="TwoRooms-v0")
    oracle = chk.NoisyOracleParams(epsilon=0.2, ignore_prob=0.5, seek_prob=0.0)
    data = chk.collect(jaxgrid.make("TwoRooms-v0"), chk.noisy_oracle_policy, oracle,
                       jax.random.PRNGKey(3), None, TINY.window, 1, 8, balance=False,
                       num_steps=48, env_id="TwoRooms-v0")  # fmt: skip
    scores = chk.predict(untrained, data.windows, data.tokens)
    threshold = float(np.median(scores))
    path = tmp_path / "checker"
    chk.save(untrained.replace(threshold=threshold), path)
    cfg = false_alarms.FalseAlarmConfig(
        checker=str(path),
        env_id="TwoRooms-v0",
        policy="oracle",
        envs=8,
        steps=48,
        out=str(tmp_path / "fa.json"),
    )
    out = false_alarms.run(cfg)
    total, rows = out["total"], out["front"]
    assert total["windows"] == 8 * 48  # every window but the last, whose next step is unknown
    assert sum(r["windows"] for r in rows.values()) == total["windows"]
    assert sum(r["positives"] for r in rows.values()) == total["positives"]
    assert sum(r["false_alarms"] for r in rows.values()) == total["false_alarms"]
    assert sum(r["missed"] for r in rows.values()) == total["missed"]
    assert total["alarms"] == total["true_alarms"] + total["false_alarms"]
    assert total["positives"] == total["true_alarms"] + total["missed"]
    assert total["alarms"] == int((scores > threshold).sum())
    assert total["positives"] == int(data.labels.sum()) > 0
    # Positives (lookahead 1) only ever face the forbidden door's cell.
    assert all(r["positives"] == 0 for g, r in rows.items() if g != "door open named")
    assert (tmp_path / "fa.json").exists()


@pytest.mark.parametrize(
    "field, value",
    [("checker", "/nonexistent"), ("env_id", "NoSuch-v0"), ("policy", "greedy"), ("envs", 0)],
)
def test_bad_input_names_the_field(tmp_path, field, value):
    path = tmp_path / "checker"
    chk.save(new_checker(TINY, jax.random.PRNGKey(0)), path)
    kwargs = {"checker": str(path), field: value}
    with pytest.raises(ValueError, match=f"FalseAlarmConfig.{field}"):
        false_alarms.FalseAlarmConfig(**kwargs)
