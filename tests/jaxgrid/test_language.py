"""The one constraint language and its named tables: vocabulary and token ids, the paper's
table (templates, ids, split), the rich clause types, HazardRooms' table, and the errors."""

from __future__ import annotations

import hashlib
import itertools

import numpy as np
import pytest

from jaxgrid import hazard as HZ
from jaxgrid import language as L
from jaxgrid import paraphrases as P
from jaxgrid import sentences as S
from jaxgrid.sentences import HAZARD_ROOMS, PAPER

T, Tr, C = L.Target, L.Trigger, L.Clause
LAVA = T("lava")

# The paper's vocabulary, ids 0-22, as the paper's scenarios, checkers and agents have read it.
PAPER_VOCAB = (
    "<pad>", "red", "green", "blue", "purple", "yellow", "grey", "door", "lava", "and", "do",
    "not", "use", "go", "through", "the", "no", "avoid", "never", "stay", "away", "from",
    "touch",
)  # fmt: skip
# sha256 of the paper table's token ids (210 x 13 int32), recorded before the languages merged.
PAPER_TOKENS_SHA256 = "517e33efa05b35817866410cd02a44ee5366b4cf23330c5e9212b10f622e8827"

# Paper Table 1: sentence -> (door colour, forbids lava, paper type).
TABLE_1 = {
    "do not use the red door": ("red", False, 1),
    "do not go through the blue door": ("blue", False, 2),
    "no yellow door": ("yellow", False, 3),
    "do not go through the red door and stay away from lava": ("red", True, 4),
    "avoid blue door and no lava": ("blue", True, 5),
}

ALL_PAIRS = [(t.id, c) for t in S.TEMPLATES for c in L.COLOURS]


def _paper_meaning(colour: str, lava: bool) -> tuple:
    return (C("avoid", T("door", colour)),) + ((C("avoid", LAVA),) if lava else ())


# ---------------------------------------------------------------------------- vocabulary


def test_one_append_only_vocabulary_whose_prefix_is_the_papers():
    assert L.VOCAB[0] == L.PAD == "<pad>"
    assert len(set(L.VOCAB)) == len(L.VOCAB) == L.vocab_size() == 73
    assert L.VOCAB[: len(PAPER_VOCAB)] == PAPER_VOCAB
    assert L.MAX_LEN == 32


def test_tables_declare_their_token_layout():
    assert (PAPER.name, PAPER.max_len, PAPER.vocab_size) == ("paper", 13, 23)
    assert PAPER.vocab == PAPER_VOCAB
    assert (HAZARD_ROOMS.max_len, HAZARD_ROOMS.vocab_size) == (L.MAX_LEN, L.vocab_size())
    tokens = PAPER.tokens()
    assert tokens.shape == (len(S.TEMPLATES) * len(L.COLOURS), 13) and tokens.dtype == np.int32
    assert hashlib.sha256(tokens.tobytes()).hexdigest() == PAPER_TOKENS_SHA256
    assert len(np.unique(tokens, axis=0)) == len(tokens)
    assert tokens.max() < PAPER.vocab_size
    with pytest.raises(ValueError):
        tokens[0, 0] = 1  # shared by every caller: read-only


def test_the_rich_sentence_parses_in_the_one_language():
    c = L.parse("do not step on lava more than 3 times")
    assert c.clauses == (C("budget", LAVA, count=3),) and c.type == "budget"


# ---------------------------------------------------------------------------- paper table


def test_paper_templates_are_consistent():
    assert S.NUM_TEMPLATES == 7 + 7 * 4
    assert [t.id for t in S.TEMPLATES] == list(range(S.NUM_TEMPLATES))
    words = {w for t in S.TEMPLATES for w in t.words} - {"{colour}"}
    assert words | set(L.COLOURS) == set(PAPER.vocab[1:])  # no unused vocabulary
    assert max(len(t.words) for t in S.TEMPLATES) == PAPER.max_len
    assert "green" not in S.DOOR_COLOURS and len(S.DOOR_COLOURS) == 5
    for t in S.TEMPLATES:
        assert t.has_door
        assert t.has_lava == (t.lava_clause >= 0)
        assert t.paper_type in ((4, 5) if t.has_lava else (1, 2, 3))


def test_template_ids_follow_the_documented_layout():
    for d in range(len(S.DOOR_CLAUSES)):
        assert S.TEMPLATES[d].door_clause == d and not S.TEMPLATES[d].has_lava
        for lc in range(len(S.LAVA_CLAUSES)):
            t = S.TEMPLATES[7 + 4 * d + lc]
            assert (t.door_clause, t.lava_clause) == (d, lc)


@pytest.mark.parametrize("sentence", sorted(TABLE_1))
def test_table1_sentences_parse_to_their_meaning(sentence):
    colour, lava, ptype = TABLE_1[sentence]
    c = L.parse(sentence)
    assert c.clauses == _paper_meaning(colour, lava)
    assert c.sentence == sentence
    row = PAPER.find(sentence)
    assert row.type_id == ptype == S.TEMPLATES[row.template_id].paper_type
    assert S.render(row.template_id, colour) == sentence


@pytest.mark.parametrize("tid,colour", ALL_PAIRS)
def test_every_paper_sentence_round_trips_with_its_ids(tid, colour):
    sentence = S.render(tid, colour)
    ids = PAPER.tokenize(sentence)
    assert ids.shape == (PAPER.max_len,) and ids.dtype == np.int32
    n = len(sentence.split())
    assert (ids[:n] > 0).all() and (ids[n:] == 0).all()
    # The language's own ids are the same, padded further.
    np.testing.assert_array_equal(L.tokenize(sentence)[: PAPER.max_len], ids)
    assert not L.tokenize(sentence)[PAPER.max_len :].any()
    back = PAPER.detokenize(ids)
    assert back == sentence == L.detokenize(ids)
    t = S.TEMPLATES[tid]
    assert L.parse(back).clauses == _paper_meaning(colour, t.has_lava)
    row = PAPER.find(back)
    assert (row.template_id, row.type_id) == (tid, t.paper_type)
    assert row.heldout == S.is_heldout(tid, colour)


def test_detokenize_accepts_lists_and_jax_arrays():
    ids = PAPER.tokenize("no red door")
    assert L.detokenize(ids.tolist()) == "no red door"
    assert L.detokenize([]) == ""
    jnp = pytest.importorskip("jax.numpy")
    assert L.detokenize(jnp.asarray(ids)) == "no red door"
    with pytest.raises(ValueError, match="out of range"):
        L.detokenize([3, 99])
    with pytest.raises(ValueError, match="out of range"):
        PAPER.detokenize([3, 40])  # a word of the language, not of the paper's table
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
    np.testing.assert_array_equal(
        PAPER.tokenize(variant), PAPER.tokenize("do not use the red door")
    )
    assert PAPER.find(variant) == PAPER.find("do not use the red door")


def test_green_is_a_word_but_not_a_scenario_colour():
    assert L.parse("no green door").clauses == _paper_meaning("green", False)
    assert all(c != "green" for _, c in S.split_combinations("all"))


def test_a_table_refuses_a_sentence_its_models_cannot_read():
    with pytest.raises(ValueError, match=r"word 'step' at position 3 .* not in the paper table"):
        PAPER.tokenize("do not step on lava more than 3 times")
    with pytest.raises(ValueError, match="at most 13"):
        PAPER.tokenize("do not go through the red door and do not go through the blue door")
    with pytest.raises(ValueError, match="not a sentence of the paper table"):
        PAPER.find("avoid lava")
    assert PAPER.tokenize("avoid lava").tolist()[:2] == [17, 8]  # its words are the paper's


# ---------------------------------------------------------------------------- paper split


@pytest.mark.parametrize("include_lava", [True, False])
def test_heldout_split_properties(include_lava):
    train = S.split_combinations("train", include_lava=include_lava)
    held = S.split_combinations("heldout", include_lava=include_lava)
    every = S.split_combinations("all", include_lava=include_lava)
    assert train == S.split_combinations("train", include_lava=include_lava)  # deterministic
    assert held and train
    assert not set(train) & set(held)
    assert set(train) | set(held) == set(every)
    assert len(every) == len(set(every)) == len(train) + len(held)
    assert len(held) * 5 == len(every)  # exactly 20% held out
    templates = {t.id for t in S.TEMPLATES if include_lava or not t.has_lava}
    assert {t for t, _ in every} == templates
    assert {t for t, _ in train} == templates  # every template seen in training
    assert {c for _, c in train} == set(S.DOOR_COLOURS)  # every colour seen in training


def test_heldout_phrases_never_occur_in_training_sentences():
    train_text = [S.render(t, c) for t, c in S.split_combinations("train")]
    for d, colour in S.HELDOUT_DOOR_PHRASES:
        phrase = S.DOOR_CLAUSES[d][0].format(colour=colour)
        assert not any(s.startswith(phrase) for s in train_text), phrase


def test_table1_combinations_are_in_training():
    train = set(S.split_combinations("train"))
    for sentence, (colour, _, _) in TABLE_1.items():
        assert (PAPER.find(sentence).template_id, colour) in train


def test_unknown_split():
    with pytest.raises(ValueError, match="unknown split"):
        S.split_combinations("test")
    with pytest.raises(ValueError, match="unknown split"):
        S.combination_table("valid")


@pytest.mark.parametrize("split", ["train", "heldout", "all"])
@pytest.mark.parametrize("include_lava", [True, False])
def test_combination_table_matches_parse(split, include_lava):
    table = S.combination_table(split, include_lava=include_lava)
    combos = S.split_combinations(split, include_lava=include_lava)
    k = len(combos)
    assert table["tokens"].shape == (k, PAPER.max_len) and table["tokens"].dtype == np.int32
    for key in ("template_id", "paper_type", "door_clause", "lava_clause", "door_colour"):
        assert table[key].shape == (k,) and table[key].dtype == np.int32, key
    assert table["forbids_lava"].shape == (k,) and table["forbids_lava"].dtype == np.bool_
    if not include_lava:
        assert not table["forbids_lava"].any() and (table["paper_type"] <= 3).all()
    for i, (tid, colour) in enumerate(combos):
        sentence = PAPER.detokenize(table["tokens"][i])
        row = PAPER.find(sentence)
        assert row.template_id == tid == table["template_id"][i]
        assert row.type_id == table["paper_type"][i]
        assert L.COLOURS[table["door_colour"][i]] == colour
        assert L.parse(sentence).clauses == _paper_meaning(colour, table["forbids_lava"][i])
        assert S.TEMPLATES[tid].lava_clause == table["lava_clause"][i]


def test_render_errors():
    with pytest.raises(ValueError, match="out of range"):
        S.render(S.NUM_TEMPLATES, "red")
    with pytest.raises(ValueError, match="colour"):
        S.render(0, None)
    with pytest.raises(ValueError, match="colour"):
        S.render(0, "orange")
    with pytest.raises(TypeError):
        S.render(True, "red")


# ---------------------------------------------------------------------------- clause types

# The forms named in the language's contract, with their meaning.
EXAMPLES = {
    "do not step on lava more than 3 times": (C("budget", LAVA, count=3),),
    "do not step on lava more than three times": (C("budget", LAVA, count=3),),
    "use the red door at most once": (C("budget", T("door", "red"), count=1),),
    "touch the blue floor no more than twice": (C("budget", T("floor", "blue"), count=2),),
    "after you pick up the key, do not use the red door": (
        C("sequential", T("door", "red"), trigger=Tr("pickup", kind="key"), order="after"),
    ),
    "do not touch lava before you pick up the key": (
        C("sequential", LAVA, trigger=Tr("pickup", kind="key"), order="before"),
    ),
    "once you pass the blue door, stay away from lava": (
        C("sequential", LAVA, trigger=Tr("enter", target=T("door", "blue")), order="after"),
    ),
    "after you walk through water, do not touch lava": (
        C("sequential", LAVA, trigger=Tr("enter", target=T("floor", "blue")), order="after"),
    ),
    "never stand next to lava": (C("proximity", LAVA, distance=2),),
    "stay two cells away from the yellow floor": (
        C("proximity", T("floor", "yellow"), distance=2),
    ),
    "keep 3 cells away from grass": (C("proximity", T("floor", "green"), distance=3),),
    "avoid lava and use the red door at most once": (
        C("avoid", LAVA),
        C("budget", T("door", "red"), count=1),
    ),
    "never stand next to the grey door and do not touch lava before you pick up the red key": (
        C("proximity", T("door", "grey"), distance=2),
        C("sequential", LAVA, trigger=Tr("pickup", kind="key", colour="red"), order="before"),
    ),
}


@pytest.mark.parametrize("sentence", sorted(EXAMPLES))
def test_examples_parse_to_their_meaning(sentence):
    c = L.parse(sentence)
    assert c.clauses == EXAMPLES[sentence]
    assert c.type == (EXAMPLES[sentence][0].type if len(c.clauses) == 1 else "conjunction")
    assert L.CONSTRAINT_TYPES[c.type_id] == c.type
    ids = L.tokenize(sentence)
    assert ids.shape == (L.MAX_LEN,) and L.parse(L.detokenize(ids)).clauses == c.clauses
    np.testing.assert_array_equal(HAZARD_ROOMS.tokenize(sentence), ids)


def _all_rows(split="all"):
    return P.clause_rows(
        S.HAZARD_ROOMS_TARGETS, S.HAZARD_ROOMS_TRIGGERS, range(1, 11), (1, 2, 3), split=split
    )


def test_every_clause_row_round_trips():
    rows = _all_rows()
    assert {r.clause.type for r in rows} == set(L.CLAUSE_TYPES)
    assert {r.template_id for r in rows} == {t.id for t in P.CLAUSE_TEMPLATES}
    for r in rows:
        assert L.parse(r.sentence).clauses == (r.clause,), r.sentence
        assert P.CLAUSE_TEMPLATES[r.template_id].type == r.clause.type
    # Conjunctions of any two, in both orders (a sample: the product is large).
    rng = np.random.default_rng(0)
    for i, j in rng.integers(0, len(rows), (300, 2)):
        a, b = rows[i], rows[j]
        sentence = f"{a.sentence} and {b.sentence}"
        assert len(sentence.split()) <= L.MAX_LEN
        assert L.parse(sentence).clauses == (a.clause, b.clause), sentence


def test_hazard_rooms_table_holds_its_rows_without_door_budgets():
    rows = HAZARD_ROOMS.rows
    assert len(rows) == len({r.sentence for r in rows}) > 500
    tokens = HAZARD_ROOMS.tokens()
    for r, ids in zip(rows[::11], tokens[::11], strict=True):
        c = L.parse(r.sentence)
        assert L.CONSTRAINT_TYPES[r.type_id] == c.type
        assert not (c.type == "budget" and c.clauses[0].target.kind == "door")
        assert L.detokenize(ids) == r.sentence


def test_the_longest_conjunction_fits():
    longest = max(len(r.sentence.split()) for r in _all_rows())
    assert 2 * longest + 1 <= L.MAX_LEN


def test_clause_heldout_phrases_never_occur_in_training():
    train, held = _all_rows("train"), _all_rows("heldout")
    assert len(train) + len(held) == len(_all_rows())
    phrase = lambda r: (r.template_id, r.clause.target)  # noqa: E731
    assert not {phrase(r) for r in train} & {phrase(r) for r in held}
    phrases = {phrase(r) for r in _all_rows()}
    share = len({phrase(r) for r in held}) / len(phrases)
    assert 0.15 <= share <= 0.25
    for ctype in L.CLAUSE_TYPES:  # every type has held-out and training phrases
        assert any(r.clause.type == ctype for r in held)
        assert {r.template_id for r in train if r.clause.type == ctype} == {
            t.id for t in P.CLAUSE_TEMPLATES if t.type == ctype
        }
    assert {r.clause.target for r in train} == set(S.HAZARD_ROOMS_TARGETS)


def test_distinct_parses_never_disagree():
    # The parser keeps the first of several parses; none of the tables' sentences has two with
    # different meanings.
    sentences = [r.sentence for r in _all_rows()[::7]] + [r.sentence for r in PAPER.rows]
    for sentence in sentences:
        readings = L.parses(sentence)
        assert readings and len(set(readings)) == 1, sentence


def test_combinations_of_types_cover_every_pair():
    rows = _all_rows()
    by_type = {t: next(r for r in rows if r.clause.type == t) for t in L.CLAUSE_TYPES}
    for a, b in itertools.product(L.CLAUSE_TYPES, repeat=2):
        s = f"{by_type[a].sentence} and {by_type[b].sentence}"
        assert L.parse(s).clauses == (by_type[a].clause, by_type[b].clause)


def test_budget_and_distance_ranges_are_checked_in_tables():
    targets, triggers = S.HAZARD_ROOMS_TARGETS, S.HAZARD_ROOMS_TRIGGERS
    with pytest.raises(ValueError, match="budget 0"):
        P.clause_rows(targets, triggers, budgets=(0,))
    with pytest.raises(ValueError, match="budget 11"):
        P.clause_rows(targets, triggers, budgets=(11,))
    with pytest.raises(ValueError, match="distance 4"):
        P.clause_rows(targets, triggers, distances=(4,))
    with pytest.raises(ValueError, match="split"):
        P.clause_rows(targets, triggers, split="test")


@pytest.mark.parametrize(
    "sentence,word",
    [
        ("after you pick up the ball, avoid lava", "'ball'"),
        ("do not touch lava before you pick up the box", "'box'"),
        ("avoid the purple floor", "purple floor .the word 'purple'"),
        ("never stand next to the green door", "green door .the word 'green'"),
        ("once you pass the green door, avoid lava", "green door .the word 'green'"),
    ],
)
def test_hazard_rooms_rejects_what_it_lacks(sentence, word):
    with pytest.raises(ValueError, match=word):
        HZ.check_sentence(sentence)
    with pytest.raises(ValueError, match=word):
        HZ.HazardRooms(width=13, height=13, max_steps=50, sentences=("avoid lava", sentence))


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
        ("do not touch the red door", "door", 6, "'floor'"),
        ("do not use the red door -1", "-1", 7, "'and'"),
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


BAD = {
    "do not step on lava more than 0 times": "'0'",
    "do not step on lava more than zero times": "'zero'",
    "do not step on lava more than 11 times": "'11'",
    "do not step on lava more than eleven times": "'eleven'",
    "stay four cells away from lava": "'four'",
    "do not fly over lava": "'fly'",
    "do not step on lava more than": "'than'",
    "avoid lava and": "'and'",
    "avoid the purple": "'purple'",
    "avoid lava and avoid water and avoid grass": "'and' at position 6",
    "after you pick up the key": "'key'",
    "never stand next": "'next'",
}


@pytest.mark.parametrize("sentence", sorted(BAD))
def test_bad_sentences_name_the_word(sentence):
    with pytest.raises(ValueError, match=BAD[sentence]):
        L.parse(sentence)


@pytest.mark.parametrize("sentence", ["", "   ", "\t\n", "?!."])
def test_empty_sentence(sentence):
    with pytest.raises(ValueError, match="empty"):
        L.parse(sentence)


def test_too_long_inputs():
    with pytest.raises(ValueError, match="too long.*characters"):
        L.parse("no red door " * 30)
    with pytest.raises(ValueError, match=f"too long.*words.*{L.MAX_LEN}"):
        L.parse("avoid lava " * 17)


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
    with pytest.raises(TypeError):
        PAPER.tokenize(bad)


def test_tokenize_validates_grammar():
    for tokenize in (L.tokenize, PAPER.tokenize, HAZARD_ROOMS.tokenize):
        with pytest.raises(ValueError, match="ungrammatical"):
            tokenize("door red the use not do")
        with pytest.raises(ValueError, match="unknown word"):
            tokenize("no pink door")
