"""Named sentence tables of the constraint language: which sentences a scenario draws.

:mod:`jaxgrid.language` is one grammar for every scenario; a :class:`SentenceTable` names the
sentences one scenario says, with their template ids, types and held-out split, and the token
layout a model of that scenario reads: ``max_len`` ids per sentence and ``vocab_size``, the
number of ids its sentences may use (the embedding a checker or policy sizes for it, so a model
trained on a table keeps its parameters however the language grows). Two tables are named:

* :data:`PAPER`: the 35 templates of Prakash et al. (2020) with each of the six colours, for the
  paper's scenarios (TwoRooms, TwoRoomsLava, ThreeRoomsKey): ``max_len`` 13, ``vocab_size`` 23,
  their historical token ids;
* :data:`HAZARD_ROOMS`: every single-clause sentence HazardRooms draws from, paraphrase
  templates of the four clause types over its targets and triggers; ``max_len`` and
  ``vocab_size`` are the whole language's (32 and 73), since HazardRooms joins two rows with
  "and" and accepts any given sentence;
* :data:`LEVELS`: every single-clause sentence of those templates over every target and
  trigger the grammar has, the whole language's token layout: a constrained MiniGrid level
  draws from its rows that name only what the level can hold, and observes given sentences
  in its layout.

The paper's table
-----------------
A template is one door clause, optionally joined by "and" to one lava clause (7 door-only and
7 x 4 conjunction templates). Template ids: door-only template ``d`` has id ``d`` (0-6); the
conjunction of door clause ``d`` and lava clause ``l`` has id ``7 + 4 * d + l`` (7-34). Paper
types 1-3 are door-only (the door clause's family: 1 "use" verbs, 2 movement verbs, 3 short
forms), 4-5 door + lava (4 for a long lava clause, 5 a short one). Table 1 of the paper maps as
"do not use the red door" -> 1, "do not go through the blue door" -> 2, "no yellow door" -> 3,
"do not go through the red door and stay away from lava" -> 4, "avoid blue door and no lava"
-> 5. The scenarios only name the five non-green :data:`DOOR_COLOURS` (green is the goal's);
"green" is a valid word that the checker never sees in training.

Held-out split: seven (door clause, colour) phrases, one per door clause
(:data:`HELDOUT_DOOR_PHRASES`), never occur in a training sentence: a (template, colour)
combination is held out iff its door clause with that colour is one of them. That is exactly
20% of the 175 combinations; every template keeps four colours, every colour appears in
training, and the paper's Table 1 examples are all training combinations.

HazardRooms' table
------------------
Its rows are :func:`jaxgrid.paraphrases.clause_rows` over HazardRooms' targets and triggers
(held-out (template, target) phrases as that module says), without door budgets.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from jaxgrid import language
from jaxgrid.constants import COLOR_TO_IDX
from jaxgrid.language import COLOURS, Target, Trigger
from jaxgrid.paraphrases import ClauseRow, check_split, clause_rows

__all__ = [
    "DOOR_CLAUSES",
    "DOOR_COLOURS",
    "HAZARD_ROOMS",
    "HAZARD_ROOMS_FLOORS",
    "HAZARD_ROOMS_TARGETS",
    "HAZARD_ROOMS_TRIGGERS",
    "HELDOUT_DOOR_PHRASES",
    "LAVA_CLAUSES",
    "LEVELS",
    "grammar_table",
    "LEVEL_TARGETS",
    "LEVEL_TRIGGERS",
    "NUM_TEMPLATES",
    "PAPER",
    "TEMPLATES",
    "SentenceRow",
    "SentenceTable",
    "Template",
    "combination_table",
    "hazard_rooms_rows",
    "is_heldout",
    "render",
    "split_combinations",
]

# --------------------------------------------------------------------------------------
# The table type
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class SentenceRow:
    """One sentence of a table: its template id, its type (the table's: a paper type 1-5, or an
    index into :data:`jaxgrid.language.CONSTRAINT_TYPES`) and whether it is held out."""

    sentence: str
    template_id: int
    type_id: int
    heldout: bool


@dataclasses.dataclass(frozen=True)
class SentenceTable:
    """A named table of sentences and the token layout its models read (module docstring)."""

    name: str
    max_len: int
    vocab_size: int
    rows: tuple[SentenceRow, ...]

    def __hash__(self) -> int:
        # Tables are static settings of environments, hashed on every jitted call: once.
        return self._hash

    @functools.cached_property
    def _hash(self) -> int:
        return hash((self.name, self.max_len, self.vocab_size, self.rows))

    def __post_init__(self):
        if not 1 <= self.max_len <= language.MAX_LEN:
            raise ValueError(f"{self.name}: max_len must be in 1..{language.MAX_LEN}")
        if not 2 <= self.vocab_size <= language.vocab_size():
            raise ValueError(f"{self.name}: vocab_size must be in 2..{language.vocab_size()}")

    @property
    def vocab(self) -> tuple[str, ...]:
        """The words of ids ``0 .. vocab_size - 1`` (a prefix of the language's vocabulary)."""
        return language.VOCAB[: self.vocab_size]

    def tokenize(self, sentence: str) -> np.ndarray:
        """Token ids of a sentence of the language: int32 ``(max_len,)``, right-padded with 0.

        Raises as :func:`jaxgrid.language.parse` for an invalid sentence, and ``ValueError``
        for one longer than ``max_len`` words or with a word whose id is ``vocab_size`` or more
        (naming the word and the table's vocabulary): its ids would not fit a model of the table.
        """
        ids = language.tokenize(sentence)
        n = int(np.count_nonzero(ids))
        if n > self.max_len:
            raise ValueError(
                f"{sentence!r} has {n} words; the {self.name} table's sentences have at most "
                f"{self.max_len}"
            )
        for pos, i in enumerate(ids[:n].tolist(), start=1):
            if i >= self.vocab_size:
                raise ValueError(
                    f"word {language.VOCAB[i]!r} at position {pos} in {sentence!r} is not in "
                    f"the {self.name} table's vocabulary: " + ", ".join(self.vocab[1:])
                )
        return ids[: self.max_len].copy()

    def tokenize_batch(self, sentences: Iterable[str]) -> np.ndarray:
        """Stack :meth:`tokenize` over sentences: int32 ``(N, max_len)``."""
        rows = [self.tokenize(s) for s in sentences]
        return np.stack(rows) if rows else np.zeros((0, self.max_len), np.int32)

    def detokenize(self, ids: Any) -> str:
        """Words of a 1-D sequence of this table's token ids, up to the first pad."""
        return language.detokenize(ids, self.vocab)

    @functools.cached_property
    def _tokens(self) -> np.ndarray:
        out = self.tokenize_batch(r.sentence for r in self.rows)
        out.setflags(write=False)
        return out

    def tokens(self) -> np.ndarray:
        """int32 ``(K, max_len)`` token ids of every row (computed once, read-only).

        The tokenizer is canonical, so every sentence of the table tokenizes to one of these
        rows: models encode the table once and each sample gathers its row
        (:func:`jaxgrid.language.sentence_index`).
        """
        return self._tokens

    @functools.cached_property
    def _by_sentence(self) -> dict[str, SentenceRow]:
        return {r.sentence: r for r in self.rows}

    def find(self, sentence: str) -> SentenceRow:
        """The row of ``sentence`` (any spelling :func:`jaxgrid.language.normalize` accepts);
        ``ValueError`` naming it when the table does not hold it."""
        row = self._by_sentence.get(" ".join(language.normalize(sentence)))
        if row is None:
            raise ValueError(f"{sentence!r} is not a sentence of the {self.name} table")
        return row


def _ids_used(words: Iterable[str]) -> int:
    """The number of ids an embedding needs to read every one of ``words``."""
    return 1 + max(language.VOCAB.index(w) for w in words)


# --------------------------------------------------------------------------------------
# The paper's table
# --------------------------------------------------------------------------------------

#: Door colours the scenarios name: the five non-green colours, in MiniGrid order.
DOOR_COLOURS: tuple[str, ...] = ("red", "blue", "purple", "yellow", "grey")
_SLOT = "{colour}"  # the colour slot inside a clause pattern

#: Door clause patterns (index = door clause id) and their paper type.
DOOR_CLAUSES: tuple[tuple[str, int], ...] = (
    ("do not use the {colour} door", 1),
    ("do not go through the {colour} door", 2),
    ("no {colour} door", 3),
    ("avoid the {colour} door", 2),
    ("avoid {colour} door", 3),
    ("never use the {colour} door", 1),
    ("stay away from the {colour} door", 2),
)
#: Lava clause patterns (index = lava clause id) and the paper type of a conjunction.
LAVA_CLAUSES: tuple[tuple[str, int], ...] = (
    ("stay away from lava", 4),
    ("no lava", 5),
    ("avoid lava", 5),
    ("do not touch the lava", 4),
)

#: Held-out (door clause id, colour) phrases; see the module docstring. Chosen by hand:
#: one colour per door clause, every door colour at least once, no Table 1 example.
HELDOUT_DOOR_PHRASES: frozenset[tuple[int, str]] = frozenset({
    (0, "blue"),    # do not use the blue door
    (1, "yellow"),  # do not go through the yellow door
    (2, "red"),     # no red door
    (3, "purple"),  # avoid the purple door
    (4, "grey"),    # avoid grey door
    (5, "blue"),    # never use the blue door
    (6, "yellow"),  # stay away from the yellow door
})  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Template:
    """One paper template: a door clause, optionally "and" a lava clause.

    Attributes:
        id: template id (0-6 door-only, 7-34 conjunctions; see the module docstring).
        text: the pattern, with ``{colour}`` where the door colour goes.
        has_door: whether the template forbids a door (always True in this table).
        has_lava: whether the template forbids lava.
        paper_type: the paper's constraint type, 1-3 door-only, 4-5 door + lava.
        door_clause: index into :data:`DOOR_CLAUSES`.
        lava_clause: index into :data:`LAVA_CLAUSES`, or -1 when there is no lava clause.
    """

    id: int
    text: str
    has_door: bool
    has_lava: bool
    paper_type: int
    door_clause: int
    lava_clause: int

    @property
    def words(self) -> tuple[str, ...]:
        """The pattern's words, with ``"{colour}"`` as the colour slot."""
        return tuple(self.text.split())


def _build_templates() -> tuple[Template, ...]:
    out = [
        Template(d, text, True, False, ptype, d, -1) for d, (text, ptype) in enumerate(DOOR_CLAUSES)
    ]
    for d, (door_text, _) in enumerate(DOOR_CLAUSES):
        for l, (lava_text, ptype) in enumerate(LAVA_CLAUSES):  # noqa: E741
            tid = len(DOOR_CLAUSES) + len(LAVA_CLAUSES) * d + l
            out.append(Template(tid, f"{door_text} and {lava_text}", True, True, ptype, d, l))
    assert [t.id for t in out] == list(range(len(out)))
    return tuple(out)


#: The paper's templates, indexed by id.
TEMPLATES: tuple[Template, ...] = _build_templates()
NUM_TEMPLATES: int = len(TEMPLATES)


def render(template_id: int, colour: str) -> str:
    """The canonical sentence of a paper template with a colour (one of :data:`COLOURS`)."""
    if isinstance(template_id, bool) or not isinstance(template_id, (int, np.integer)):
        raise TypeError(f"template_id must be an int, got {type(template_id).__name__}")
    if not 0 <= template_id < NUM_TEMPLATES:
        raise ValueError(f"template_id {template_id} out of range [0, {NUM_TEMPLATES})")
    if colour not in COLOURS:
        raise ValueError(f"colour must be one of {COLOURS}, got {colour!r}")
    return TEMPLATES[int(template_id)].text.replace(_SLOT, colour)


def is_heldout(template_id: int, colour: str) -> bool:
    """Whether (template, colour) belongs to the held-out split (never seen in training)."""
    return (TEMPLATES[template_id].door_clause, colour) in HELDOUT_DOOR_PHRASES


_PAPER_WORDS = {w for t in TEMPLATES for w in t.words if w != _SLOT} | set(COLOURS)
#: The paper's table: every template with each of the six colours (K = 210, template-major).
PAPER = SentenceTable(
    name="paper",
    max_len=max(len(t.words) for t in TEMPLATES),
    vocab_size=_ids_used(_PAPER_WORDS),
    rows=tuple(
        SentenceRow(render(t.id, c), t.id, t.paper_type, is_heldout(t.id, c))
        for t in TEMPLATES
        for c in COLOURS
    ),
)


def split_combinations(split: str, include_lava: bool = True) -> list[tuple[int, str]]:
    """(template id, colour) combinations of a split, sorted by template then colour.

    Args:
        split: ``"train"``, ``"heldout"`` or ``"all"``.
        include_lava: include the door + lava templates (False for scenarios without lava).

    Only :data:`DOOR_COLOURS` are used. Raises ``ValueError`` for an unknown split.
    """
    check_split(split)
    out = []
    for t in TEMPLATES:
        if t.has_lava and not include_lava:
            continue
        for c in DOOR_COLOURS:
            held = is_heldout(t.id, c)
            if split == "all" or (split == "heldout") == held:
                out.append((t.id, c))
    return out


def combination_table(split: str, include_lava: bool = True) -> dict[str, np.ndarray]:
    """Numeric arrays describing every combination of a split, row k = combination k.

    Keys (K = number of combinations, order as :func:`split_combinations`):
        ``tokens`` int32 (K, 13) (:data:`PAPER`'s ids); ``template_id``, ``paper_type``,
        ``door_clause`` and ``lava_clause`` (-1 if none) int32 (K,); ``door_colour`` int32 (K,)
        MiniGrid colour index; ``forbids_lava`` bool (K,).

    All values are numeric, so ``jax.tree.map(jnp.asarray, table)`` puts it on device.
    """
    combos = split_combinations(split, include_lava=include_lava)
    rows: Sequence[Template] = [TEMPLATES[t] for t, _ in combos]
    return {
        "tokens": PAPER.tokenize_batch(render(t, c) for t, c in combos),
        "template_id": np.array([t.id for t in rows], dtype=np.int32),
        "paper_type": np.array([t.paper_type for t in rows], dtype=np.int32),
        "door_clause": np.array([t.door_clause for t in rows], dtype=np.int32),
        "lava_clause": np.array([t.lava_clause for t in rows], dtype=np.int32),
        "door_colour": np.array([COLOR_TO_IDX[c] for _, c in combos], dtype=np.int32),
        "forbids_lava": np.array([t.has_lava for t in rows], dtype=bool),
    }


# --------------------------------------------------------------------------------------
# HazardRooms' table
# --------------------------------------------------------------------------------------


#: HazardRooms' floor colours: water, grass and yellow floor.
HAZARD_ROOMS_FLOORS: tuple[str, ...] = ("blue", "green", "yellow")
#: HazardRooms' targets: lava, the three floors, then the five door colours.
HAZARD_ROOMS_TARGETS: tuple[Target, ...] = (
    Target("lava"),
    *(Target("floor", c) for c in HAZARD_ROOMS_FLOORS),
    *(Target("door", c) for c in DOOR_COLOURS),
)
#: HazardRooms' triggers: picking up the key, or entering any target.
HAZARD_ROOMS_TRIGGERS: tuple[Trigger, ...] = (Trigger("pickup", kind="key"),) + tuple(
    Trigger("enter", target=t) for t in HAZARD_ROOMS_TARGETS
)


def hazard_rooms_rows(split: str, budgets: Iterable[int], distances: Iterable[int]):
    """The :class:`ClauseRow` s HazardRooms draws from: :func:`clause_rows` over its targets
    and triggers, without door budgets (a route crosses each door once, so a door budget
    would never bind)."""
    rows = clause_rows(HAZARD_ROOMS_TARGETS, HAZARD_ROOMS_TRIGGERS, budgets, distances, split)
    return [r for r in rows if r.clause.type != "budget" or r.clause.target.kind != "door"]


def grammar_table(name: str, rows: Sequence[ClauseRow]) -> SentenceTable:
    """A table of the whole language's token layout (:data:`jaxgrid.language.MAX_LEN`, every
    word) over clause rows, each row's type its clause's."""
    return SentenceTable(
        name=name,
        max_len=language.MAX_LEN,
        vocab_size=language.vocab_size(),
        rows=tuple(SentenceRow(r.sentence, r.template_id,
                               language.CONSTRAINT_TYPES.index(r.clause.type), r.heldout)
                   for r in rows),
    )  # fmt: skip


_EVERY = (range(1, language.MAX_BUDGET + 1), range(1, language.MAX_DISTANCE + 1))

#: HazardRooms' table: its rows for every budget and distance the language allows (a
#: HazardRooms env draws those of its ``split``, ``budgets`` and ``distances``).
HAZARD_ROOMS = grammar_table("HazardRooms", hazard_rooms_rows("all", *_EVERY))


# --------------------------------------------------------------------------------------
# The levels' table
# --------------------------------------------------------------------------------------

#: Every target of the grammar: lava, then the floor and the door of each colour.
LEVEL_TARGETS: tuple[Target, ...] = (
    Target("lava"),
    *(Target("floor", c) for c in COLOURS),
    *(Target("door", c) for c in COLOURS),
)
#: The levels' triggers: picking up a key, a ball or a box, or entering any target.
LEVEL_TRIGGERS: tuple[Trigger, ...] = tuple(
    Trigger("pickup", kind=k) for k in ("key", "ball", "box")
) + tuple(Trigger("enter", target=t) for t in LEVEL_TARGETS)

#: The levels' table: :func:`clause_rows` over :data:`LEVEL_TARGETS` and
#: :data:`LEVEL_TRIGGERS` for every budget and distance the language allows (held-out phrases
#: as :mod:`jaxgrid.paraphrases` says); the whole language's token layout.
LEVELS = grammar_table("levels", clause_rows(LEVEL_TARGETS, LEVEL_TRIGGERS, *_EVERY))
