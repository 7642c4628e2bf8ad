"""``jaxgrid.language``'s sentence tables: the one lookup from token rows to table rows."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrid
from jaxgrid import language


def test_grammar_table_holds_every_sentence_once():
    table = language.sentence_table()
    assert table.shape == (len(language.TEMPLATES) * len(language.COLOURS), language.MAX_LEN)
    assert len(np.unique(table, axis=0)) == len(table)
    sentence = language.render(3, "blue")
    row = language.sentence_index(language.tokenize(sentence)[None], table)[0]
    assert language.detokenize(table[row]) == sentence


def test_env_tables():
    env = jaxgrid.make("TwoRoomsLava-v0")
    table = language.sentence_table(env)
    np.testing.assert_array_equal(table, env.constraint_table()["tokens"])
    plain = language.sentence_table(jaxgrid.make("MiniGrid-Empty-5x5-v0"))
    assert plain.shape == (1, language.MAX_LEN) and (plain == 0).all()


def test_host_lookup_names_an_unknown_sentence():
    table = language.sentence_table(jaxgrid.make("TwoRooms-v0"))  # no lava clauses
    odd = language.tokenize("avoid the red door and no lava")[None]
    with pytest.raises(ValueError, match="avoid the red door and no lava"):
        language.sentence_index(odd, table)


def test_traced_lookup_marks_an_unknown_sentence_with_minus_one():
    table = language.sentence_table()
    rows = np.stack([table[5], table[0], np.zeros_like(table[0])])
    index = jax.jit(language.sentence_index)(jnp.asarray(rows), jnp.asarray(table))
    np.testing.assert_array_equal(index, [5, 0, -1])


def test_sentence_lengths_count_real_words():
    tokens = language.tokenize_batch(["no red door", "do not go through the blue door"])
    np.testing.assert_array_equal(language.sentence_lengths(tokens), [3, 7])
    assert int(language.sentence_lengths(np.zeros(language.MAX_LEN, np.int32))) == 0
