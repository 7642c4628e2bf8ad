"""The declared interface of a constrained environment: every registered id with a constraint
is a ConstrainedEnvironment, and observes, reports and stores what the interface declares."""

from __future__ import annotations

import jax
import numpy as np
import pytest

import jaxgrid
from jaxgrid import monitor as M
from jaxgrid.constrained import (
    ConstrainedEnvironment,
    ConstrainedExtras,
    EpisodeConstraint,
    language_table,
    sentence_tokens,
)
from jaxgrid.sentences import PAPER

CONSTRAINED = ("TwoRooms-v0", "TwoRoomsLava-v0", "ThreeRoomsKey-v0", "HazardRooms-v0")
KEY = jax.random.PRNGKey(0)


def _shapes(env):
    """Abstract ``(state, reset timestep, step timestep)``: traced, never compiled."""

    def run(key):
        state, first = env.reset(key)
        return state, first, env.step(state, 2)[1]

    return jax.eval_shape(run, KEY)


def test_the_constrained_ids_are_exactly_those_that_observe_a_constraint():
    for env_id in jaxgrid.registered_ids():
        env = jaxgrid.make(env_id)
        constrained = isinstance(env, ConstrainedEnvironment)
        assert constrained == (env_id in CONSTRAINED), env_id
        if not constrained:
            assert language_table(env) is PAPER  # models built for it keep the paper's sizes
            assert sentence_tokens(env).shape == (1, PAPER.max_len)


@pytest.mark.parametrize("env_id", CONSTRAINED)
def test_a_constrained_env_observes_reports_and_stores_what_it_declares(env_id):
    env = jaxgrid.make(env_id)
    state, first, step = _shapes(env)
    for ts in (first, step):
        assert tuple(sorted(ts.observation)) == tuple(sorted(env.OBSERVATION_KEYS))
        assert tuple(sorted(ts.info)) == tuple(sorted(env.INFO_KEYS))
    assert isinstance(state.extras, ConstrainedExtras)
    assert isinstance(state.extras.constraint, EpisodeConstraint)
    assert isinstance(state.extras.monitor, M.Monitor)
    table = env.language_table
    assert language_table(env) is table
    assert first.observation["constraint"].shape == (table.max_len,)
    rows = env.constraint_table()
    tokens = sentence_tokens(env)
    np.testing.assert_array_equal(tokens, rows["tokens"])
    assert tokens.shape[1] == table.max_len and tokens.max() < table.vocab_size
    assert jax.tree.leaves(rows["spec"])[0].shape == (len(tokens), M.NUM_CLAUSES)
    assert env.every_sentence_in_table == (env_id != "HazardRooms-v0")
