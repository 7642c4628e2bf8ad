"""The rich constraint language: meaning of every clause type, tables, split, errors."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from jaxgrid import hazard as HZ
from jaxgrid import hazard_language as HL
from jaxgrid import language as L

T, Tr, C = HL.Target, HL.Trigger, HL.Clause
LAVA = T("lava")

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
    c = HL.parse(sentence)
    assert c.clauses == EXAMPLES[sentence]
    assert c.type == (EXAMPLES[sentence][0].type if len(c.clauses) == 1 else "conjunction")
    assert HL.CONSTRAINT_TYPES[c.type_id] == c.type
    ids = HL.tokenize(sentence)
    assert ids.shape == (HL.MAX_LEN,) and HL.parse(HL.detokenize(ids)).clauses == c.clauses


def test_vocabulary_extends_the_papers_append_only():
    assert HL.VOCAB[: len(L.VOCAB)] == L.VOCAB
    assert len(set(HL.VOCAB)) == len(HL.VOCAB) == HL.vocab_size()
    assert HL.MAX_LEN >= L.MAX_LEN


@pytest.mark.parametrize("template", L.TEMPLATES, ids=lambda t: str(t.id))
def test_every_paper_sentence_means_the_same(template):
    for colour in L.COLOURS:
        sentence = L.render(template.id, colour)
        paper = L.parse(sentence)
        rich = HL.parse(sentence)
        expected = (C("avoid", T("door", colour)),) + (
            (C("avoid", LAVA),) if paper.forbids_lava else ()
        )
        assert rich.clauses == expected
        # Same ids for the paper's words: the paper's tokens are a prefix of the rich ones.
        np.testing.assert_array_equal(HL.tokenize(sentence)[: L.MAX_LEN], L.tokenize(sentence))


def _all_rows(split="all"):
    return HL.clause_rows(
        HZ.scenario_targets(), HZ.scenario_triggers(), range(1, 11), (1, 2, 3), split=split
    )


def test_every_table_sentence_round_trips():
    rows = _all_rows()
    assert {r.clause.type for r in rows} == set(HL.CLAUSE_TYPES)
    assert {r.template_id for r in rows} == {t.id for t in HL.TEMPLATES}
    for r in rows:
        assert HL.parse(r.sentence).clauses == (r.clause,), r.sentence
        assert HL.TEMPLATES[r.template_id].type == r.clause.type
    # Conjunctions of any two, in both orders (a sample: the product is large).
    rng = np.random.default_rng(0)
    for i, j in rng.integers(0, len(rows), (300, 2)):
        a, b = rows[i], rows[j]
        sentence = f"{a.sentence} and {b.sentence}"
        assert len(sentence.split()) <= HL.MAX_LEN
        assert HL.parse(sentence).clauses == (a.clause, b.clause), sentence


def test_the_longest_conjunction_fits():
    rows = _all_rows()
    longest = max(len(r.sentence.split()) for r in rows)
    assert 2 * longest + 1 <= HL.MAX_LEN


def test_heldout_phrases_never_occur_in_training():
    train, held = _all_rows("train"), _all_rows("heldout")
    assert len(train) + len(held) == len(_all_rows())
    phrase = lambda r: (r.template_id, r.clause.target)  # noqa: E731
    assert not {phrase(r) for r in train} & {phrase(r) for r in held}
    phrases = {phrase(r) for r in _all_rows()}
    share = len({phrase(r) for r in held}) / len(phrases)
    assert 0.15 <= share <= 0.25
    for ctype in HL.CLAUSE_TYPES:  # every type has held-out and training phrases
        assert any(r.clause.type == ctype for r in held)
        assert {r.template_id for r in train if r.clause.type == ctype} == {
            t.id for t in HL.TEMPLATES if t.type == ctype
        }
    assert {r.clause.target for r in train} == set(HZ.scenario_targets())


def test_distinct_parses_never_disagree():
    # The parser keeps the first of several parses; check none of the table's sentences has
    # two with different meanings.
    for r in _all_rows()[::7]:
        fail = HL._Failure()
        words = HL.normalize(r.sentence)
        meanings = {v for v, j in HL._SENTENCE(words, 0, fail) if j == len(words)}
        assert len(meanings) == 1, r.sentence


# ---------------------------------------------------------------------------- errors

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
        HL.parse(sentence)


def test_budget_and_distance_ranges_are_checked_in_tables():
    targets, triggers = HZ.scenario_targets(), HZ.scenario_triggers()
    with pytest.raises(ValueError, match="budget 0"):
        HL.clause_rows(targets, triggers, budgets=(0,))
    with pytest.raises(ValueError, match="budget 11"):
        HL.clause_rows(targets, triggers, budgets=(11,))
    with pytest.raises(ValueError, match="distance 4"):
        HL.clause_rows(targets, triggers, distances=(4,))
    with pytest.raises(ValueError, match="split"):
        HL.clause_rows(targets, triggers, split="test")


@pytest.mark.parametrize(
    "sentence,word",
    [
        ("after you pick up the ball, avoid lava", "'ball'"),
        ("do not touch lava before you pick up the box", "'box'"),
        ("avoid the purple floor", "'purple' floor"),
        ("never stand next to the green door", "'green' door"),
        ("once you pass the green door, avoid lava", "'green' door"),
    ],
)
def test_the_scenario_rejects_what_it_lacks(sentence, word):
    with pytest.raises(ValueError, match=word):
        HZ.check_sentence(sentence)
    with pytest.raises(ValueError, match=word):
        HZ.HazardRooms(width=13, height=13, max_steps=50, sentences=("avoid lava", sentence))


def test_combinations_of_types_cover_every_pair():
    rows = _all_rows()
    by_type = {t: next(r for r in rows if r.clause.type == t) for t in HL.CLAUSE_TYPES}
    for a, b in itertools.product(HL.CLAUSE_TYPES, repeat=2):
        s = f"{by_type[a].sentence} and {by_type[b].sentence}"
        assert HL.parse(s).clauses == (by_type[a].clause, by_type[b].clause)
