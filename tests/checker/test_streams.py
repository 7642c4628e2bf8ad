"""checker.data's streams (the memory checker's data): from ``BatchedAutoReset(HazardRooms)``,
each frame's label is the violation of the step taken from it, starts where episodes begin,
tokens constant within an episode, the actions into each frame; guided streams follow the
oracle; relabelled streams say the step into each frame."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxgrid
from checker.data import BEHAVIOUR, collect_streams, relabel
from checker.protocol import NO_ACTION
from checker.train import MemoryTrainConfig
from jaxgrid.constants import FORWARD


def test_stream_labels_are_the_next_steps_violation(streams):
    d = streams
    assert d["frames"].shape == (16, 60, 7, 7, 3) and d["tokens"].shape[:2] == (16, 60)
    assert d["starts"][:, 0].all()
    # a frame that is not a start was produced by the step taken from the frame before it
    inner = ~d["starts"][:, 1:]
    np.testing.assert_array_equal(d["label"][:, :-1][inner], d["violation"][:, 1:][inner])
    assert (d["violation"][d["starts"]] == 0).all() and (d["cost"][d["starts"]] == 0).all()
    # the constraint is one sentence per episode
    same = (d["tokens"][:, 1:] == d["tokens"][:, :-1]).all(-1)
    assert same[inner].all()
    assert d["label"].sum() > 0  # the behaviour policy does violate
    np.testing.assert_array_equal(d["next_cost"][:, :-1][inner], d["cost"][:, 1:][inner])


def test_stream_actions_lead_into_each_frame(streams):
    """``action`` is the action taken into each frame: none into an episode's first, one the
    behaviour takes otherwise, and a step forward wherever the step into the frame cost (only
    entering a cell is a constraint event)."""
    d = streams
    assert (d["action"][d["starts"]] == NO_ACTION).all()
    inner = d["action"][~d["starts"]]
    assert set(np.unique(inner).tolist()) == {a for a, p in enumerate(BEHAVIOUR) if p > 0}
    assert 0.45 < (inner == FORWARD).mean() < 0.65  # BEHAVIOUR's 0.55, over ~900 steps
    costly = d["cost"] > 0
    assert costly.sum() > 0 and (d["action"][costly] == FORWARD).all()


@pytest.mark.slow
def test_guided_streams_follow_the_oracle_on_alternate_halves(streams):
    """``guided=1``: even streams follow the oracle that obeys the constraint, so none of them
    violates; odd streams plan through hazards. Both reach the goal far more often than the
    random behaviour, whose streams are ``streams`` (same env, key and sizes)."""
    env = jaxgrid.make("HazardRooms-v0")
    d = collect_streams(env, jax.random.PRNGKey(0), 16, 60, guided=1.0)
    assert d["frames"].shape == streams["frames"].shape
    assert d["label"][0::2].sum() == 0 and d["label"][1::2].sum() > 0
    # episodes that end before the stream does: the oracle reaches the goal in well under 60
    assert d["starts"][:, 1:].sum() > 2 * streams["starts"][:, 1:].sum()
    with pytest.raises(ValueError, match="guided"):
        collect_streams(env, jax.random.PRNGKey(0), 4, 4, guided=1.5)
    with pytest.raises(ValueError, match="guided"):
        MemoryTrainConfig(guided=-0.1)


def test_into_labels_are_the_violation_of_the_step_into_each_frame(streams):
    into = relabel(streams, 0)
    assert relabel(streams, 1) is streams
    np.testing.assert_array_equal(into["label"], streams["violation"])
    assert into["label"].dtype == np.int32 and into["label"][streams["starts"]].sum() == 0
    # the same violations, one frame later, except those on an episode's last step
    inner = ~streams["starts"][:, 1:]
    np.testing.assert_array_equal(into["label"][:, 1:][inner], streams["label"][:, :-1][inner])
    with pytest.raises(ValueError, match="lookahead must be one of"):
        relabel(streams, 2)
    with pytest.raises(ValueError, match="MemoryTrainConfig.lookahead must be one of"):
        MemoryTrainConfig(lookahead=2)
