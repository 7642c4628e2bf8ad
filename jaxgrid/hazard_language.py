"""A richer constraint language: avoid, budget, sequential and proximity clauses.

The paper's grammar (:mod:`jaxgrid.language`) forbids entering one door colour, optionally
with lava. This grammar says more, in the spirit of HazardWorld (Yang et al. 2021) and TTCT
(Dong et al. 2024):

* **avoid**: "do not use the red door", "avoid lava", "stay away from the blue floor";
* **budget**: "do not step on lava more than three times", "use the red door at most once",
  "touch the blue floor no more than twice" (1 to 10 times, as a word or a digit);
* **sequential**: "after you pick up the key, do not use the red door", "do not touch lava
  before you pick up the key", "once you pass the blue door, stay away from lava";
* **proximity**: "never stand next to lava", "stay two cells away from the yellow floor";
* the **conjunction** of any two clauses with "and" (a trigger scopes its own clause only).

Numbers are read whole, with their sign ("-1", "minus two"), decimal point ("1.5") and digit
groups ("1,000"), and any number a clause cannot take is refused by name, with the range it
allows: budgets count 1 to :data:`MAX_BUDGET` times, distances are 1 to :data:`MAX_DISTANCE`
cells (the monitor's zones reach at most ``MAX_DISTANCE - 1`` cells out), written as the words
"one" to "ten" or as plain digits.

Every sentence of the paper's grammar is also a sentence here, with the same meaning (avoid
clauses). The vocabulary extends :data:`jaxgrid.language.VOCAB` append-only, so the paper's
words keep their token ids and a paper sentence tokenizes to the same ids (with more padding:
:data:`MAX_LEN` is longer). The paper's scenarios keep the paper's language, so checkers and
agents trained on them are unchanged.

Meaning (:class:`HazardConstraint`, one :class:`Clause` per clause)
-------------------------------------------------------------------
Targets are cells: a door of a colour, lava, or a floor tile of a colour ("water" is the blue
floor, "grass" the green floor). An *event* is the agent entering a target cell; for a
proximity clause, entering any cell within Manhattan distance ``distance - 1`` of a target
cell ("next to" is distance 2: the target and its four neighbours are forbidden). A trigger
is picking up an object (key, ball, box, optionally coloured) or entering a target cell.

* avoid: every event is a violation;
* budget ``count`` K: every event costs; each one beyond the K-th is a violation;
* sequential ``order="after"``: events once the trigger has happened are violations;
  ``order="before"``: events until the trigger happens are violations; a trigger and an
  event in the same step are judged with the trigger not yet happened;
* proximity: every entry into the forbidden zone is a violation.

:mod:`jaxgrid.monitor` is the jittable state machine that applies these rules.

Tables and the held-out split
-----------------------------
:func:`clause_rows` enumerates the single-clause sentences a scenario draws from, given its
targets, triggers and budgets, each from a paraphrase *template* (:data:`TEMPLATES`). As in
the paper's language, a (template, target) phrase is held out when ``(template index within
its type + target index) % 5 == 0``: a fifth of the phrases, every template keeping most of
its targets and every target appearing in training.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Iterable, Sequence
from typing import Any

import numpy as np

from jaxgrid import language
from jaxgrid.constants import COLOR_NAMES

__all__ = [
    "CLAUSE_TYPES",
    "CONSTRAINT_TYPES",
    "MAX_BUDGET",
    "MAX_DISTANCE",
    "MAX_LEN",
    "TEMPLATES",
    "VOCAB",
    "Clause",
    "ClauseRow",
    "HazardConstraint",
    "Target",
    "Trigger",
    "clause_rows",
    "detokenize",
    "numeral_value",
    "parse",
    "tokenize",
    "vocab_size",
]

COLOURS: tuple[str, ...] = tuple(COLOR_NAMES)
_NUMBER_WORDS = ("one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten")
#: Budgets count 1 to MAX_BUDGET events; proximity distances are 1 to MAX_DISTANCE cells.
MAX_BUDGET = 10
MAX_DISTANCE = 3

#: Clause types, and constraint types (a conjunction is its own type), by id.
CLAUSE_TYPES: tuple[str, ...] = ("avoid", "budget", "sequential", "proximity")
CONSTRAINT_TYPES: tuple[str, ...] = CLAUSE_TYPES + ("conjunction",)

#: The vocabulary: the paper's, then this grammar's words. Append-only: ids must stay stable.
VOCAB: tuple[str, ...] = language.VOCAB + (
    "more", "than", "times", "time", "once", "twice", "at", "most",
    "after", "before", "until", "you", "pick", "up", "key", "ball", "box",
    "pass", "step", "on", "walk", "floor", "water", "grass",
    "stand", "next", "to", "cells", "cell", "keep",
    *_NUMBER_WORDS,
    *(str(k) for k in range(1, MAX_BUDGET + 1)),
)  # fmt: skip
_WORD_TO_ID = {w: i for i, w in enumerate(VOCAB)}
PAD = language.PAD
#: Token ids per sentence (right-padded); longer sentences are rejected.
MAX_LEN: int = 32
#: Number words outside the grammar's numbers, read so that they are refused by value.
_OTHER_NUMBER_WORDS = {
    "zero": 0, "eleven": 11, "twelve": 12, "thirteen": 13, "fourteen": 14, "fifteen": 15,
    "sixteen": 16, "seventeen": 17, "eighteen": 18, "nineteen": 19, "twenty": 20, "thirty": 30,
    "forty": 40, "fifty": 50, "sixty": 60, "seventy": 70, "eighty": 80, "ninety": 90,
    "hundred": 100, "thousand": 1000, "million": 10**6, "billion": 10**9,
}  # fmt: skip
#: Words that make the number after them negative.
_MINUS_WORDS = ("minus", "negative")
_DIGITS = re.compile(r"[+-]?\d+(?:[.,]\d+)*")


def vocab_size() -> int:
    """Number of token ids, padding included."""
    return len(VOCAB)


# --------------------------------------------------------------------------------------
# Meaning
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Target:
    """Cells an event enters: ``kind`` "door", "lava" or "floor"; ``colour`` None for lava."""

    kind: str
    colour: str | None = None

    @property
    def phrase(self) -> str:
        """Canonical noun phrase: "lava", "the red door", "the blue floor"."""
        return "lava" if self.kind == "lava" else f"the {self.colour} {self.kind}"


@dataclasses.dataclass(frozen=True)
class Trigger:
    """What arms or disarms a sequential clause.

    ``action`` "pickup" (``kind`` key, ball or box; ``colour`` None for any colour) or "enter"
    (``target``, a :class:`Target`).
    """

    action: str
    kind: str | None = None
    colour: str | None = None
    target: Target | None = None


@dataclasses.dataclass(frozen=True)
class Clause:
    """One clause's meaning; see the module docstring for the rules.

    Attributes:
        type: "avoid", "budget", "sequential" or "proximity".
        target: the cells whose entry is the event.
        count: events allowed before the first violation (budget K; 0 otherwise).
        distance: proximity: the least Manhattan distance to keep from every target cell
            (cells nearer are the forbidden zone); 0 otherwise.
        trigger: the sequential clause's trigger; None otherwise.
        order: "after" (events once triggered violate) or "before" (events until then).
    """

    type: str
    target: Target
    count: int = 0
    distance: int = 0
    trigger: Trigger | None = None
    order: str | None = None

    @property
    def radius(self) -> int:
        """Manhattan radius of the forbidden zone around each target cell (0: the cell)."""
        return max(self.distance - 1, 0)


@dataclasses.dataclass(frozen=True)
class HazardConstraint:
    """A parsed sentence: one clause, or two joined by "and"."""

    clauses: tuple[Clause, ...]
    sentence: str

    @property
    def type(self) -> str:
        """The clause's type, or "conjunction" for two clauses."""
        return self.clauses[0].type if len(self.clauses) == 1 else "conjunction"

    @property
    def type_id(self) -> int:
        """Index of :attr:`type` in :data:`CONSTRAINT_TYPES`."""
        return CONSTRAINT_TYPES.index(self.type)


# --------------------------------------------------------------------------------------
# Grammar: a small backtracking parser over words. Each parser maps (words, i) to every
# (value, j) it can match; the furthest failure and what was expected there make the error.
# --------------------------------------------------------------------------------------
Parser = Callable[[Sequence[str], int, "_Failure"], list]


class _Failure:
    def __init__(self):
        self.pos, self.expected = -1, []
        self.bad_number: tuple[int, str, str] | None = None  # (position, numeral, why)

    def note(self, pos: int, what: str) -> None:
        if pos > self.pos:
            self.pos, self.expected = pos, [what]
        elif pos == self.pos and what not in self.expected:
            self.expected.append(what)

    def note_number(self, pos: int, numeral: str, why: str) -> None:
        """A numeral where a number goes, but not one the slot allows: the first one wins."""
        if self.bad_number is None or pos < self.bad_number[0]:
            self.bad_number = (pos, numeral, why)


def _lit(phrase: str, value: Any = None) -> Parser:
    words = phrase.split()

    def parse(ws, i, fail):
        for k, w in enumerate(words):
            if i + k >= len(ws) or ws[i + k] != w:
                fail.note(i + k, repr(w))
                return []
        return [(value, i + len(words))]

    return parse


def _word(options: dict[str, Any], what: str) -> Parser:
    def parse(ws, i, fail):
        if i < len(ws) and ws[i] in options:
            return [(options[ws[i]], i + 1)]
        fail.note(i, what)
        return []

    return parse


def _alt(*parsers: Parser) -> Parser:
    def parse(ws, i, fail):
        return [r for p in parsers for r in p(ws, i, fail)]

    return parse


def _seq(*parsers: Parser, build: Callable[..., Any]) -> Parser:
    """Match ``parsers`` in order; ``build`` gets the non-None values in order."""

    def parse(ws, i, fail):
        partial = [((), i)]
        for p in parsers:
            partial = [
                (vals + (() if v is None else (v,)), j2)
                for vals, j in partial
                for v, j2 in p(ws, j, fail)
            ]
            if not partial:
                return []
        return [(build(*vals), j) for vals, j in partial]

    return parse


_COLOUR = _word({c: c for c in COLOURS}, f"a colour ({', '.join(COLOURS)})")
#: The numerals the grammar accepts, with their values: the words and the plain digits.
_NUMBER = {w: k for k, w in enumerate(_NUMBER_WORDS, start=1)} | {
    str(k): k for k in range(1, MAX_BUDGET + 1)
}


def numeral_value(word: str) -> int | float | None:
    """The value of a one-word numeral, or None when ``word`` is none.

    Numerals are the number words (the grammar's "one" to "ten", and "zero", "eleven" to
    "ninety", "hundred" to "billion") and digits with an optional sign, decimal point or digit
    groups ("3", "-1", "+2", "1.5", "1,000": :func:`normalize` keeps them whole). The value
    is what the numeral says, so that a number the grammar does not accept can be refused by
    what it is (negative, fractional or out of range) instead of being misread.
    """
    if word in _NUMBER:
        return _NUMBER[word]
    if word in _OTHER_NUMBER_WORDS:
        return _OTHER_NUMBER_WORDS[word]
    if _DIGITS.fullmatch(word):
        plain = word.replace(",", "")
        return float(plain) if "." in plain else int(plain)
    return None


def _why_not(value: int | float, high: int) -> str:
    """Why a numeral of ``value`` is not one of the grammar's numbers 1..``high``."""
    if value < 0:
        return "is negative"
    if value != int(value):
        return "is not a whole number"
    if not 1 <= value <= high:
        return "is out of range"
    return "is not written as the grammar writes numbers (no sign, leading zero or comma)"


def _number(high: int, what: str, rule: str) -> Parser:
    """A number 1..``high``: a word ("three") or plain digits ("3"); ``what`` names the slot
    in grammar errors, ``rule`` states its range in number errors.

    Any other numeral in its place ("-1", "minus two", "1.5", "+2", "eleven") fails with a
    :meth:`_Failure.note_number`, which :func:`parse` reports before any grammar error: the
    sentence says a number the monitor cannot represent, and no other reading is meant.
    """

    def parse(ws, i, fail):
        j = i + 1 if i < len(ws) and ws[i] in _MINUS_WORDS else i
        value = numeral_value(ws[j]) if j < len(ws) else None
        if value is None:
            fail.note(i, what)
            return []
        if j == i and ws[i] in _NUMBER and _NUMBER[ws[i]] <= high:
            return [(_NUMBER[ws[i]], i + 1)]
        value = -value if j > i else value
        fail.note_number(i, " ".join(ws[i : j + 1]), f"{_why_not(value, high)}: {rule}")
        return []

    return parse


_COUNT = _number(
    MAX_BUDGET,
    f"a count (1 to {MAX_BUDGET}, as a word or a digit)",
    f"a budget counts 1 to {MAX_BUDGET} times, written one to ten or 1 to {MAX_BUDGET}",
)
_DIST = _number(
    MAX_DISTANCE,
    f"a distance (1 to {MAX_DISTANCE} cells)",
    f"a distance is 1 to {MAX_DISTANCE} cells, written one to three or 1 to {MAX_DISTANCE}",
)

_DOOR = _seq(_lit("the"), _COLOUR, _lit("door"), build=lambda c: Target("door", c))
_LAVA = _alt(_lit("lava", Target("lava")), _lit("the lava", Target("lava")))
_FLOOR = _alt(
    _seq(_lit("the"), _COLOUR, _lit("floor"), build=lambda c: Target("floor", c)),
    _lit("water", Target("floor", "blue")),
    _lit("grass", Target("floor", "green")),
)
_GROUND = _alt(_LAVA, _FLOOR)
_TARGET = _alt(_DOOR, _GROUND)
#: Verbs of entering, by target kind (the first three are the ones tables use).
DOOR_VERBS = ("use", "go through", "pass", "pass through")
GROUND_VERBS = ("step on", "touch", "walk through", "walk on")
_EVENT = _alt(
    *(_seq(_lit(v), _DOOR, build=lambda t: t) for v in DOOR_VERBS),
    *(_seq(_lit(v), _GROUND, build=lambda t: t) for v in GROUND_VERBS),
)
_NEG = _alt(_lit("do not"), _lit("never"))

# Avoid: the paper's clauses, generalised to every target.
_AVOID = _alt(
    _seq(_NEG, _EVENT, build=lambda t: Clause("avoid", t)),
    _seq(_lit("avoid"), _TARGET, build=lambda t: Clause("avoid", t)),
    _seq(_lit("stay away from"), _TARGET, build=lambda t: Clause("avoid", t)),
    # The paper's short forms.
    _seq(_lit("no"), _COLOUR, _lit("door"), build=lambda c: Clause("avoid", Target("door", c))),
    _seq(_lit("avoid"), _COLOUR, _lit("door"), build=lambda c: Clause("avoid", Target("door", c))),
    _lit("no lava", Clause("avoid", Target("lava"))),
)

_TIMES = _alt(
    _lit("once", 1),
    _lit("twice", 2),
    _seq(_COUNT, _alt(_lit("times"), _lit("time")), build=lambda k: k),
)


def _budget(t, k):
    return Clause("budget", t, count=k)


_BUDGET = _alt(
    _seq(_NEG, _EVENT, _lit("more than"), _TIMES, build=_budget),
    _seq(_EVENT, _lit("at most"), _TIMES, build=_budget),
    _seq(_EVENT, _lit("no more than"), _TIMES, build=_budget),
)

_OBJECT = _alt(
    *(_lit(f"the {k}", (k, None)) for k in ("key", "ball", "box")),
    *(
        _seq(_lit("the"), _COLOUR, _lit(k), build=lambda c, k=k: (k, c))
        for k in ("key", "ball", "box")
    ),
)
_TRIGGER = _alt(
    _seq(_lit("pick up"), _OBJECT, build=lambda o: Trigger("pickup", kind=o[0], colour=o[1])),
    _seq(_EVENT, build=lambda t: Trigger("enter", target=t)),
)


def _sequential(order):
    return lambda trig, core: Clause("sequential", core.target, trigger=trig, order=order)


_SEQUENTIAL = _alt(
    _seq(_alt(_lit("after you"), _lit("once you")), _TRIGGER, _AVOID, build=_sequential("after")),
    _seq(
        _NEG,
        _EVENT,
        _alt(_lit("before you"), _lit("until you")),
        _TRIGGER,
        build=lambda t, trig: Clause("sequential", t, trigger=trig, order="before"),
    ),
)

_PROXIMITY = _alt(
    _seq(_NEG, _lit("stand next to"), _TARGET, build=lambda t: Clause("proximity", t, distance=2)),
    _seq(
        _alt(_lit("stay"), _lit("keep")),
        _DIST,
        _alt(_lit("cells"), _lit("cell")),
        _lit("away from"),
        _TARGET,
        build=lambda d, t: Clause("proximity", t, distance=d),
    ),
)

_CLAUSE = _alt(_AVOID, _BUDGET, _SEQUENTIAL, _PROXIMITY)
_SENTENCE = _alt(
    _seq(_CLAUSE, build=lambda c: (c,)),
    _seq(_CLAUSE, _lit("and"), _CLAUSE, build=lambda a, b: (a, b)),
)


#: Lower-case words, punctuation as separators; the paper language's rules and checks.
normalize = language.normalize


def _check_words(words: list[str], sentence: str) -> None:
    """Raise for a word outside the vocabulary; numerals pass, for the grammar to judge where
    they stand (a count and a distance allow different numbers)."""
    for pos, w in enumerate(words, start=1):
        if (w in _WORD_TO_ID and w != PAD) or w in _MINUS_WORDS or numeral_value(w) is not None:
            continue
        raise ValueError(
            f"unknown word {w!r} at position {pos} in {sentence!r}; valid vocabulary: "
            + ", ".join(VOCAB[1:])
        )


def parse(sentence: str) -> HazardConstraint:
    """Compile a sentence into its :class:`HazardConstraint`.

    Raises ``TypeError`` for a non-string and ``ValueError`` naming the problem: too long,
    non-ASCII, empty, an unknown word (listing the vocabulary), a number its clause cannot
    take (negative, fractional, out of range or signed, with the range allowed), or the first
    word where the grammar fails, with its 1-based position and what was expected.
    """
    words = normalize(sentence)
    if not words:
        raise ValueError(f"empty constraint {sentence!r}: expected e.g. 'avoid lava'")
    if len(words) > MAX_LEN:
        raise ValueError(f"constraint too long: {len(words)} words (at most {MAX_LEN})")
    _check_words(words, sentence)
    fail = _Failure()
    parses = _SENTENCE(words, 0, fail)
    done = [v for v, j in parses if j == len(words)]
    for _, j in parses:  # a whole sentence followed by more words
        if j < len(words):
            fail.note(j, "the end of the sentence (at most two clauses)")
    if done:
        # Distinct parses always agree in meaning (tests check it); keep the first.
        return HazardConstraint(clauses=done[0], sentence=" ".join(words))
    if fail.bad_number is not None:
        pos, numeral, why = fail.bad_number
        raise ValueError(f"number {numeral!r} at position {pos + 1} in {sentence!r} {why}")
    more = ["'and'"] if "'and'" not in fail.expected and _ends_clause(words, fail.pos) else []
    expected = " or ".join(fail.expected + more)
    if fail.pos >= len(words):
        raise ValueError(
            f"incomplete constraint {sentence!r}: it ends after {words[-1]!r} at position "
            f"{len(words)}; expected {expected}"
        )
    w = words[fail.pos]
    raise ValueError(
        f"ungrammatical constraint {sentence!r}: unexpected word {w!r} at position "
        f"{fail.pos + 1}; expected {expected}"
    )


def _ends_clause(words: list[str], pos: int) -> bool:
    """Whether a whole first clause ends exactly at ``pos`` (so "and" may follow)."""
    if "and" in words[:pos]:
        return False
    return any(j == pos for _, j in _CLAUSE(words, 0, _Failure()))


# --------------------------------------------------------------------------------------
# Token ids
# --------------------------------------------------------------------------------------


def tokenize(sentence: str) -> np.ndarray:
    """Token ids of a valid sentence: int32 ``(MAX_LEN,)``, right-padded with 0."""
    parse(sentence)
    words = normalize(sentence)
    ids = np.zeros((MAX_LEN,), np.int32)
    ids[: len(words)] = [_WORD_TO_ID[w] for w in words]
    return ids


def detokenize(ids: Any) -> str:
    """Words of a 1-D sequence of token ids, up to the first pad."""
    return language.detokenize(ids, VOCAB)


# --------------------------------------------------------------------------------------
# Templates and tables
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Template:
    """A paraphrase of one clause type.

    ``text`` has slots: ``{t}`` the target phrase, ``{v0}``/``{v1}``/``{v2}`` the target
    kind's entering verb (:data:`DOOR_VERBS` / :data:`GROUND_VERBS`), ``{k}`` a count phrase
    ("once", "twice", "three times"), ``{d}`` a distance word, ``{tr}`` a trigger phrase.
    ``index`` is the template's position within its type.
    """

    id: int
    type: str
    index: int
    text: str
    order: str | None = None
    distance: int = 0  # fixed distance of "next to" forms; 0: from the {d} slot


def _templates() -> tuple[Template, ...]:
    spec = {
        "avoid": [
            ("do not {v0} {t}",),
            ("do not {v1} {t}",),
            ("never {v0} {t}",),
            ("never {v2} {t}",),
            ("avoid {t}",),
            ("stay away from {t}",),
        ],
        "budget": [
            ("do not {v0} {t} more than {k}",),
            ("{v0} {t} at most {k}",),
            ("{v1} {t} no more than {k}",),
            ("never {v2} {t} more than {k}",),
        ],
        "sequential": [
            ("after you {tr} do not {v0} {t}", "after"),
            ("once you {tr} avoid {t}", "after"),
            ("after you {tr} never {v1} {t}", "after"),
            ("do not {v0} {t} before you {tr}", "before"),
            ("never {v1} {t} until you {tr}", "before"),
        ],
        "proximity": [
            ("never stand next to {t}", None, 2),
            ("do not stand next to {t}", None, 2),
            ("stay {d} cells away from {t}",),
            ("keep {d} cells away from {t}",),
        ],
    }
    out = []
    for ctype in CLAUSE_TYPES:
        for index, row in enumerate(spec[ctype]):
            text, order, distance = row + (None, 0)[len(row) - 1 :]
            out.append(Template(len(out), ctype, index, text, order, distance))
    return tuple(out)


#: Every clause template, by id.
TEMPLATES: tuple[Template, ...] = _templates()


def _verbs(target: Target) -> tuple[str, ...]:
    return DOOR_VERBS if target.kind == "door" else GROUND_VERBS


def _count_phrase(k: int) -> str:
    return {1: "once", 2: "twice"}.get(k, f"{_NUMBER_WORDS[k - 1]} times")


def _trigger_phrase(trigger: Trigger) -> str:
    if trigger.action == "pickup":
        colour = f"{trigger.colour} " if trigger.colour else ""
        return f"pick up the {colour}{trigger.kind}"
    return f"{_verbs(trigger.target)[2]} {trigger.target.phrase}"


def render(template: Template, clause: Clause, target_phrase: str | None = None) -> str:
    """The sentence of ``template`` filled with ``clause`` (``target_phrase`` overrides)."""
    t = clause.target
    verbs = _verbs(t)
    return template.text.format(
        t=target_phrase or t.phrase,
        v0=verbs[0],
        v1=verbs[1],
        v2=verbs[2],
        k=_count_phrase(clause.count) if clause.count else "",
        d=_NUMBER_WORDS[clause.distance - 1] if clause.distance else "",
        tr=_trigger_phrase(clause.trigger) if clause.trigger else "",
    )


@dataclasses.dataclass(frozen=True)
class ClauseRow:
    """One single-clause sentence of a table, its meaning, template and split."""

    sentence: str
    clause: Clause
    template_id: int
    heldout: bool


def clause_rows(
    targets: Sequence[Target],
    triggers: Sequence[Trigger],
    budgets: Iterable[int] = range(1, MAX_BUDGET + 1),
    distances: Iterable[int] = (2, 3),
    split: str = "all",
) -> list[ClauseRow]:
    """Every single-clause sentence over the given targets, triggers, budgets and distances.

    Rows are ordered by template, then target, then parameter. The held-out rule is in the
    module docstring; ``split`` is "train", "heldout" or "all". A sequential clause whose
    trigger enters its own target is left out (it is never armed before its event).
    """
    if split not in ("train", "heldout", "all"):
        raise ValueError(f"unknown split {split!r}; expected 'train', 'heldout' or 'all'")
    budgets, distances = list(budgets), list(distances)
    for k in budgets:
        if not 1 <= k <= MAX_BUDGET:
            raise ValueError(f"budget {k} out of range: budgets count 1 to {MAX_BUDGET} times")
    for d in distances:
        if not 1 <= d <= MAX_DISTANCE:
            raise ValueError(f"distance {d} out of range: 1 to {MAX_DISTANCE} cells")
    rows = []
    for tpl in TEMPLATES:
        for ti, target in enumerate(targets):
            held = (tpl.index + ti) % 5 == 0
            if split != "all" and held != (split == "heldout"):
                continue
            if tpl.type == "avoid":
                clauses = [Clause("avoid", target)]
            elif tpl.type == "budget":
                clauses = [Clause("budget", target, count=k) for k in budgets]
            elif tpl.type == "sequential":
                clauses = [
                    Clause("sequential", target, trigger=tr, order=tpl.order)
                    for tr in triggers
                    if tr.target != target
                ]
            else:
                ds = [tpl.distance] if tpl.distance else distances
                clauses = [Clause("proximity", target, distance=d) for d in ds]
            rows += [ClauseRow(render(tpl, c), c, tpl.id, held) for c in clauses]
    return rows
