"""Sentence tables as models read them: an env's table of token rows, and the one lookup from
token rows to table rows."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrid
from jaxgrid import language, sentences
from jaxgrid.constrained import language_table, sentence_tokens
from jaxgrid.sentences import PAPER


def test_paper_table_holds_every_sentence_once():
    table = PAPER.tokens()
    assert table.shape == (len(sentences.TEMPLATES) * len(language.COLOURS), PAPER.max_len)
    assert len(np.unique(table, axis=0)) == len(table)
    sentence = sentences.render(3, "blue")
    row = language.sentence_index(PAPER.tokenize(sentence)[None], table)[0]
    assert language.detokenize(table[row]) == sentence


def test_env_tables():
    env = jaxgrid.make("TwoRoomsLava-v0")
    table = sentence_tokens(env)
    np.testing.assert_array_equal(table, env.constraint_table()["tokens"])
    assert language_table(env) is PAPER
    plain_env = jaxgrid.make("MiniGrid-Empty-5x5-v0")
    plain = sentence_tokens(plain_env)
    assert plain.shape == (1, PAPER.max_len) and (plain == 0).all()
    assert language_table(plain_env) is PAPER  # models for it keep the paper's sizes
    hazard = jaxgrid.make("HazardRooms-v0")
    assert language_table(hazard) is sentences.HAZARD_ROOMS
    assert sentence_tokens(hazard).shape[1] == language.MAX_LEN


def test_host_lookup_names_an_unknown_sentence():
    table = sentence_tokens(jaxgrid.make("TwoRooms-v0"))  # no lava clauses
    odd = PAPER.tokenize("avoid the red door and no lava")[None]
    with pytest.raises(ValueError, match="avoid the red door and no lava"):
        language.sentence_index(odd, table)


def test_traced_lookup_marks_an_unknown_sentence_with_minus_one():
    table = PAPER.tokens()
    rows = np.stack([table[5], table[0], np.zeros_like(table[0])])
    index = jax.jit(language.sentence_index)(jnp.asarray(rows), jnp.asarray(table))
    np.testing.assert_array_equal(index, [5, 0, -1])


def test_sentence_lengths_count_real_words():
    tokens = PAPER.tokenize_batch(["no red door", "do not go through the blue door"])
    np.testing.assert_array_equal(language.sentence_lengths(tokens), [3, 7])
    assert int(language.sentence_lengths(np.zeros(PAPER.max_len, np.int32))) == 0
