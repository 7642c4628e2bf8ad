"""Tests of the constraint language: grammar, tokenizer, errors, held-out split, tables."""

from __future__ import annotations

import numpy as np
import pytest

from jaxgrid import language as L
from jaxgrid.constants import COLOR_TO_IDX

# Paper Table 1: sentence -> (door colour, forbids lava, paper type).
TABLE_1 = {
    "do not use the red door": ("red", False, 1),
    "do not go through the blue door": ("blue", False, 2),
    "no yellow door": ("yellow", False, 3),
    "do not go through the red door and stay away from lava": ("red", True, 4),
    "avoid blue door and no lava": ("blue", True, 5),
}

ALL_PAIRS = [(t.id, c) for t in L.TEMPLATES for c in L.COLOURS]


# ---------------------------------------------------------------------------- tables


def test_vocab_and_templates_are_consistent():
    assert L.VOCAB[0] == "<pad>"
    assert len(set(L.VOCAB)) == len(L.VOCAB) == L.vocab_size()
    assert L.NUM_TEMPLATES == 7 + 7 * 4
    assert [t.id for t in L.TEMPLATES] == list(range(L.NUM_TEMPLATES))
    words = {w for t in L.TEMPLATES for w in t.words} - {"{colour}"}
    assert words | set(L.COLOURS) == set(L.VOCAB[1:])  # no unused vocabulary
    assert max(len(t.words) for t in L.TEMPLATES) == L.MAX_LEN
    assert "green" not in L.DOOR_COLOURS and len(L.DOOR_COLOURS) == 5
    for t in L.TEMPLATES:
        assert t.has_door
        assert t.has_lava == (t.lava_clause >= 0)
        assert t.paper_type in ((4, 5) if t.has_lava else (1, 2, 3))


def test_template_ids_follow_the_documented_layout():
    for d in range(len(L.DOOR_CLAUSES)):
        assert L.TEMPLATES[d].door_clause == d and not L.TEMPLATES[d].has_lava
        for lc in range(len(L.LAVA_CLAUSES)):
            t = L.TEMPLATES[7 + 4 * d + lc]
            assert (t.door_clause, t.lava_clause) == (d, lc)


# ---------------------------------------------------------------------------- parse


@pytest.mark.parametrize("sentence", sorted(TABLE_1))
def test_table1_sentences_parse_to_their_meaning(sentence):
    colour, lava, ptype = TABLE_1[sentence]
    c = L.parse(sentence)
    assert c.colour == colour
    assert c.forbidden_door_colours == frozenset({colour})
    assert c.forbids_lava is lava
    assert c.paper_type == ptype
    assert c.colour_index == COLOR_TO_IDX[colour]
    assert c.sentence == sentence
    assert L.TEMPLATES[c.template_id].paper_type == ptype


@pytest.mark.parametrize("tid,colour", ALL_PAIRS)
def test_every_combination_round_trips(tid, colour):
    sentence = L.render(tid, colour)
    ids = L.tokenize(sentence)
    assert ids.shape == (L.MAX_LEN,) and ids.dtype == np.int32
    n = len(sentence.split())
    assert (ids[:n] > 0).all() and (ids[n:] == 0).all()
    back = L.detokenize(ids)
    assert back == sentence
    c = L.parse(back)
    t = L.TEMPLATES[tid]
    assert (c.template_id, c.colour, c.paper_type) == (tid, colour, t.paper_type)
    assert c.forbids_lava == t.has_lava
    assert c.forbidden_door_colours == frozenset({colour})


def test_detokenize_accepts_lists_and_jax_arrays():
    ids = L.tokenize("no red door")
    assert L.detokenize(ids.tolist()) == "no red door"
    assert L.detokenize([]) == ""
    jnp = pytest.importorskip("jax.numpy")
    assert L.detokenize(jnp.asarray(ids)) == "no red door"
    with pytest.raises(ValueError, match="out of range"):
        L.detokenize([3, 99])
    with pytest.raises(ValueError, match="1-D"):
        L.detokenize(ids[None])


@pytest.mark.parametrize(
    "variant",
    [
        "Do NOT use the RED door",
        "do not use the red door.",
        "  do   not use\tthe red\ndoor  ",
        "do, not; use the (red) door!",
        "do-not-use-the-red-door",
    ],
)
def test_normalisation(variant):
    assert L.normalize(variant) == "do not use the red door".split()
    assert L.parse(variant) == L.parse("do not use the red door")
    np.testing.assert_array_equal(L.tokenize(variant), L.tokenize("do not use the red door"))


def test_green_is_a_word_but_not_a_scenario_colour():
    assert L.parse("no green door").colour == "green"
    assert all(c != "green" for _, c in L.split_combinations("all"))


# ---------------------------------------------------------------------------- errors


def test_unknown_word_names_the_word_and_the_vocabulary():
    with pytest.raises(ValueError, match="'orange'") as e:
        L.parse("do not use the orange door")
    msg = str(e.value)
    assert "position 5" in msg
    assert all(w in msg for w in L.VOCAB[1:])


def test_unknown_word_is_reported_before_grammar():
    with pytest.raises(ValueError, match="unknown word 'please'"):
        L.parse("door red please")


@pytest.mark.parametrize(
    "sentence,word,pos,expected",
    [
        ("door red the use not do", "door", 1, "'do'"),
        ("do not use red door", "red", 4, "'the'"),
        ("do not use the door", "door", 5, "a colour"),
        ("no red door lava", "lava", 4, "'and'"),
        ("no lava and no red door", "lava", 2, "a colour"),
        ("no red door and no blue door", "blue", 6, "'lava'"),
        ("do not touch the red door", "touch", 3, "'use'"),
    ],
)
def test_ungrammatical_order_names_word_position_and_expectation(sentence, word, pos, expected):
    with pytest.raises(ValueError, match="ungrammatical") as e:
        L.parse(sentence)
    msg = str(e.value)
    assert f"unexpected word '{word}' at position {pos}" in msg
    assert expected in msg


@pytest.mark.parametrize(
    "sentence,last", [("do not use the", "the"), ("no red door and", "and"), ("avoid", "avoid")]
)
def test_incomplete_sentence(sentence, last):
    with pytest.raises(ValueError, match=f"ends after '{last}'"):
        L.parse(sentence)


@pytest.mark.parametrize("sentence", ["", "   ", "\t\n", "?!."])
def test_empty_sentence(sentence):
    with pytest.raises(ValueError, match="empty"):
        L.parse(sentence)


def test_too_long_inputs():
    with pytest.raises(ValueError, match="too long.*characters"):
        L.parse("no red door " * 30)
    with pytest.raises(ValueError, match=f"too long.*words.*{L.MAX_LEN}"):
        L.parse("do not go through the red door and do not touch the lava lava")


def test_non_ascii_names_the_character():
    with pytest.raises(ValueError, match="'é'"):
        L.parse("do not use the red doér")
    with pytest.raises(ValueError, match="U\\+2019"):
        L.parse("don\u2019t use the red door")


@pytest.mark.parametrize("bad", [None, 3, b"no red door", ["no", "red", "door"]])
def test_non_string_is_a_type_error(bad):
    with pytest.raises(TypeError):
        L.parse(bad)
    with pytest.raises(TypeError):
        L.tokenize(bad)


def test_tokenize_validates_grammar():
    with pytest.raises(ValueError, match="ungrammatical"):
        L.tokenize("door red the use not do")
    with pytest.raises(ValueError, match="unknown word"):
        L.tokenize("no pink door")


def test_render_errors():
    with pytest.raises(ValueError, match="out of range"):
        L.render(L.NUM_TEMPLATES, "red")
    with pytest.raises(ValueError, match="colour"):
        L.render(0, None)
    with pytest.raises(ValueError, match="colour"):
        L.render(0, "orange")
    with pytest.raises(TypeError):
        L.render(True, "red")


# ---------------------------------------------------------------------------- split


@pytest.mark.parametrize("include_lava", [True, False])
def test_heldout_split_properties(include_lava):
    train = L.split_combinations("train", include_lava=include_lava)
    held = L.split_combinations("heldout", include_lava=include_lava)
    every = L.split_combinations("all", include_lava=include_lava)
    assert train == L.split_combinations("train", include_lava=include_lava)  # deterministic
    assert held and train
    assert not set(train) & set(held)
    assert set(train) | set(held) == set(every)
    assert len(every) == len(set(every)) == len(train) + len(held)
    assert len(held) * 5 == len(every)  # exactly 20% held out
    templates = {t.id for t in L.TEMPLATES if include_lava or not t.has_lava}
    assert {t for t, _ in every} == templates
    assert {t for t, _ in train} == templates  # every template seen in training
    assert {c for _, c in train} == set(L.DOOR_COLOURS)  # every colour seen in training


def test_heldout_phrases_never_occur_in_training_sentences():
    train_text = [L.render(t, c) for t, c in L.split_combinations("train")]
    for d, colour in L.HELDOUT_DOOR_PHRASES:
        phrase = L.DOOR_CLAUSES[d][0].format(colour=colour)
        assert not any(s.startswith(phrase) for s in train_text), phrase


def test_table1_combinations_are_in_training():
    train = set(L.split_combinations("train"))
    for sentence in TABLE_1:
        c = L.parse(sentence)
        assert (c.template_id, c.colour) in train


def test_unknown_split():
    with pytest.raises(ValueError, match="unknown split"):
        L.split_combinations("test")
    with pytest.raises(ValueError, match="unknown split"):
        L.combination_table("valid")


# ---------------------------------------------------------------------------- table


@pytest.mark.parametrize("split", ["train", "heldout", "all"])
@pytest.mark.parametrize("include_lava", [True, False])
def test_combination_table_matches_parse(split, include_lava):
    table = L.combination_table(split, include_lava=include_lava)
    combos = L.split_combinations(split, include_lava=include_lava)
    k = len(combos)
    assert table["tokens"].shape == (k, L.MAX_LEN) and table["tokens"].dtype == np.int32
    for key in ("template_id", "paper_type", "door_clause", "lava_clause", "door_colour"):
        assert table[key].shape == (k,) and table[key].dtype == np.int32, key
    assert table["forbids_lava"].shape == (k,) and table["forbids_lava"].dtype == np.bool_
    if not include_lava:
        assert not table["forbids_lava"].any() and (table["paper_type"] <= 3).all()
    for i, (tid, colour) in enumerate(combos):
        c = L.parse(L.detokenize(table["tokens"][i]))
        assert c.template_id == tid == table["template_id"][i]
        assert c.colour == colour
        assert c.colour_index == table["door_colour"][i]
        assert c.paper_type == table["paper_type"][i]
        assert c.forbids_lava == table["forbids_lava"][i]
        assert L.TEMPLATES[tid].lava_clause == table["lava_clause"][i]
