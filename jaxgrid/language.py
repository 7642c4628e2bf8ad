"""The constraint language: one grammar, vocabulary, tokenizer and parser for every scenario.

An agent is told in English what it must not do, and :func:`parse` compiles the sentence into
its meaning, a :class:`Constraint` of one or two :class:`Clause` s that :mod:`jaxgrid.monitor`
judges exactly. The clause types (in the spirit of HazardWorld, Yang et al. 2021, and TTCT,
Dong et al. 2024):

* **avoid**: "do not use the red door", "avoid lava", "stay away from the blue floor", and the
  paper's short forms "no red door", "avoid blue door", "no lava";
* **budget**: "do not step on lava more than three times", "use the red door at most once",
  "touch the blue floor no more than twice" (1 to 10 times, as a word or a digit);
* **sequential**: "after you pick up the key, do not use the red door", "do not touch lava
  before you pick up the key", "once you pass the blue door, stay away from lava";
* **proximity**: "never stand next to lava", "stay two cells away from the yellow floor";
* the **conjunction** of any two clauses with "and" (a trigger scopes its own clause only).

Every sentence of the paper (Prakash et al. 2020, Table 1: "do not go through the red door and
stay away from lava") is a sentence here: the conjunction of an avoid-door clause and an
avoid-lava one. Which sentences a scenario draws, with their template ids and held-out split,
is a named table of :mod:`jaxgrid.sentences` (the paper's 35 templates are one).

Meaning
-------
Targets are cells: a door of a colour, lava, or a floor tile of a colour ("water" is the blue
floor, "grass" the green floor). An *event* is the agent entering a target cell; for a
proximity clause, entering any cell within Manhattan distance ``distance - 1`` of a target
cell ("next to" is distance 2). A trigger is picking up an object (key, ball, box, optionally
coloured) or entering a target cell. avoid: every event is a violation; budget ``count`` K:
every event costs, each one beyond the K-th is a violation; sequential ``order="after"``:
events once the trigger has happened are violations, ``order="before"``: events until it
happens (a trigger and an event in the same step are judged with the trigger not yet
happened); proximity: every entry into the forbidden zone is a violation.

Vocabulary, normalisation, numbers
----------------------------------
:data:`VOCAB` is fixed and append-only: a word's token id is its index, 0 pads, and its first
23 words are the paper's, so every paper sentence keeps its historical ids. Case is ignored,
every ASCII character other than a letter or digit separates words and runs of separators
collapse ("Do NOT use the red door!" is "do not use the red door"); non-ASCII is refused. A
numeral keeps its sign, decimal point and digit groups ("-1", "+2", "1.5", "1,000" are one word
each), so a number is never read as another: a number a clause cannot take is refused by name
with the range it allows (budgets 1 to :data:`MAX_BUDGET`, distances 1 to :data:`MAX_DISTANCE`).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxgrid.constants import COLOR_NAMES
from jaxgrid.parsing import (
    MINUS_WORDS,
    NUMBER_WORDS,
    Failure,
    alt,
    lit,
    number,
    numeral_value,
    seq,
    word,
)

__all__ = [
    "CLAUSE_TYPES",
    "COLOURS",
    "CONSTRAINT_TYPES",
    "DOOR_VERBS",
    "GROUND_VERBS",
    "MAX_BUDGET",
    "MAX_CHARS",
    "MAX_DISTANCE",
    "MAX_LEN",
    "PAD",
    "VOCAB",
    "Clause",
    "Constraint",
    "Target",
    "Trigger",
    "detokenize",
    "normalize",
    "parse",
    "parses",
    "sentence_index",
    "sentence_lengths",
    "tokenize",
    "vocab_size",
]

#: Colours the grammar accepts, in MiniGrid index order (red 0, green 1, ..., grey 5).
COLOURS: tuple[str, ...] = tuple(COLOR_NAMES)
#: Budgets count 1 to MAX_BUDGET events; proximity distances are 1 to MAX_DISTANCE cells.
MAX_BUDGET = 10
MAX_DISTANCE = 3

#: Clause types, and constraint types (a conjunction is its own type), by id.
CLAUSE_TYPES: tuple[str, ...] = ("avoid", "budget", "sequential", "proximity")
CONSTRAINT_TYPES: tuple[str, ...] = CLAUSE_TYPES + ("conjunction",)

PAD = "<pad>"
#: The vocabulary; a word's token id is its index. Append-only: ids must stay stable.
VOCAB: tuple[str, ...] = (
    PAD,
    # the paper's words (ids 1-22): colours in MiniGrid order, nouns, "and", verbs
    "red", "green", "blue", "purple", "yellow", "grey",
    "door", "lava", "and",
    "do", "not", "use", "go", "through", "the",
    "no", "avoid", "never", "stay", "away", "from", "touch",
    # budgets, sequences, proximity
    "more", "than", "times", "time", "once", "twice", "at", "most",
    "after", "before", "until", "you", "pick", "up", "key", "ball", "box",
    "pass", "step", "on", "walk", "floor", "water", "grass",
    "stand", "next", "to", "cells", "cell", "keep",
    *NUMBER_WORDS,
    *(str(k) for k in range(1, len(NUMBER_WORDS) + 1)),
)  # fmt: skip
_WORD_TO_ID = {w: i for i, w in enumerate(VOCAB)}
#: Token ids per sentence (right-padded); longer sentences are refused.
MAX_LEN: int = 32
#: Inputs longer than this many characters are rejected before any other processing.
MAX_CHARS: int = 200

# A word: a numeral with its sign (spaces after the sign allowed: "- 2" is still negative),
# decimal point and digit groups, when no letter or digit follows it ("1st" is an ordinary
# word); else a run of letters and digits.
_WORD = re.compile(r"(?:[+-]\s*)?\d+(?:[.,]\d+)*(?![a-z0-9])|[a-z0-9]+")
_SPACE = re.compile(r"\s+")


def vocab_size() -> int:
    """Number of token ids of the whole language, padding included."""
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
class Constraint:
    """A parsed sentence: one clause, or two joined by "and"; ``sentence`` is normalised."""

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
# Grammar (combinators of :mod:`jaxgrid.parsing`)
# --------------------------------------------------------------------------------------
_COLOUR = word({c: c for c in COLOURS}, f"a colour ({', '.join(COLOURS)})")
_COUNT = number(
    MAX_BUDGET,
    f"a count (1 to {MAX_BUDGET}, as a word or a digit)",
    f"a budget counts 1 to {MAX_BUDGET} times, written one to ten or 1 to {MAX_BUDGET}",
)
_DIST = number(
    MAX_DISTANCE,
    f"a distance (1 to {MAX_DISTANCE} cells)",
    f"a distance is 1 to {MAX_DISTANCE} cells, written one to three or 1 to {MAX_DISTANCE}",
)

_DOOR = seq(lit("the"), _COLOUR, lit("door"), build=lambda c: Target("door", c))
_LAVA = alt(lit("lava", Target("lava")), lit("the lava", Target("lava")))
_FLOOR = alt(
    seq(lit("the"), _COLOUR, lit("floor"), build=lambda c: Target("floor", c)),
    lit("water", Target("floor", "blue")),
    lit("grass", Target("floor", "green")),
)
_GROUND = alt(_LAVA, _FLOOR)
_TARGET = alt(_DOOR, _GROUND)
#: Verbs of entering, by target kind (the first three are the ones tables use).
DOOR_VERBS = ("use", "go through", "pass", "pass through")
GROUND_VERBS = ("step on", "touch", "walk through", "walk on")
_EVENT = alt(
    *(seq(lit(v), _DOOR, build=lambda t: t) for v in DOOR_VERBS),
    *(seq(lit(v), _GROUND, build=lambda t: t) for v in GROUND_VERBS),
)
_NEG = alt(lit("do not"), lit("never"))

_AVOID = alt(
    seq(_NEG, _EVENT, build=lambda t: Clause("avoid", t)),
    seq(lit("avoid"), _TARGET, build=lambda t: Clause("avoid", t)),
    seq(lit("stay away from"), _TARGET, build=lambda t: Clause("avoid", t)),
    # The paper's short forms.
    seq(lit("no"), _COLOUR, lit("door"), build=lambda c: Clause("avoid", Target("door", c))),
    seq(lit("avoid"), _COLOUR, lit("door"), build=lambda c: Clause("avoid", Target("door", c))),
    lit("no lava", Clause("avoid", Target("lava"))),
)

_TIMES = alt(
    lit("once", 1),
    lit("twice", 2),
    seq(_COUNT, alt(lit("times"), lit("time")), build=lambda k: k),
)


def _budget(t, k):
    return Clause("budget", t, count=k)


_BUDGET = alt(
    seq(_NEG, _EVENT, lit("more than"), _TIMES, build=_budget),
    seq(_EVENT, lit("at most"), _TIMES, build=_budget),
    seq(_EVENT, lit("no more than"), _TIMES, build=_budget),
)

_OBJECT = alt(
    *(lit(f"the {k}", (k, None)) for k in ("key", "ball", "box")),
    *(
        seq(lit("the"), _COLOUR, lit(k), build=lambda c, k=k: (k, c))
        for k in ("key", "ball", "box")
    ),
)
_TRIGGER = alt(
    seq(lit("pick up"), _OBJECT, build=lambda o: Trigger("pickup", kind=o[0], colour=o[1])),
    seq(_EVENT, build=lambda t: Trigger("enter", target=t)),
)


def _sequential(order):
    return lambda trig, core: Clause("sequential", core.target, trigger=trig, order=order)


_SEQUENTIAL = alt(
    seq(alt(lit("after you"), lit("once you")), _TRIGGER, _AVOID, build=_sequential("after")),
    seq(
        _NEG,
        _EVENT,
        alt(lit("before you"), lit("until you")),
        _TRIGGER,
        build=lambda t, trig: Clause("sequential", t, trigger=trig, order="before"),
    ),
)

_PROXIMITY = alt(
    seq(_NEG, lit("stand next to"), _TARGET, build=lambda t: Clause("proximity", t, distance=2)),
    seq(
        alt(lit("stay"), lit("keep")),
        _DIST,
        alt(lit("cells"), lit("cell")),
        lit("away from"),
        _TARGET,
        build=lambda d, t: Clause("proximity", t, distance=d),
    ),
)

_CLAUSE = alt(_AVOID, _BUDGET, _SEQUENTIAL, _PROXIMITY)
_SENTENCE = alt(
    seq(_CLAUSE, build=lambda c: (c,)),
    seq(_CLAUSE, lit("and"), _CLAUSE, build=lambda a, b: (a, b)),
)


def normalize(sentence: str) -> list[str]:
    """Split a sentence into lower-case words, ignoring punctuation and extra whitespace.

    Every ASCII character that is not a letter or a digit acts as a separator, except the
    sign, decimal point and digit-group commas of a numeral, which stay in its word ("-1",
    "+2", "1.5", "1,000"; "- 2" is "-2"). Raises ``TypeError`` for a non-string and
    ``ValueError`` for input over :data:`MAX_CHARS` characters or containing a non-ASCII
    character. No vocabulary check is done here.
    """
    if not isinstance(sentence, str):
        raise TypeError(f"a constraint must be a str, got {type(sentence).__name__}")
    if len(sentence) > MAX_CHARS:
        raise ValueError(f"constraint too long: {len(sentence)} characters (at most {MAX_CHARS})")
    for i, ch in enumerate(sentence):
        if not ch.isascii():
            raise ValueError(
                f"non-ASCII character {ch!r} (U+{ord(ch):04X}) at index {i} of {sentence!r}; "
                "constraints are plain ASCII English"
            )
    return [_SPACE.sub("", w) for w in _WORD.findall(sentence.lower())]


def _check_words(words: list[str], sentence: str) -> None:
    """Raise for a word outside the vocabulary; numerals pass, for the grammar to judge where
    they stand (a count and a distance allow different numbers)."""
    for pos, w in enumerate(words, start=1):
        if (w in _WORD_TO_ID and w != PAD) or w in MINUS_WORDS or numeral_value(w) is not None:
            continue
        raise ValueError(
            f"unknown word {w!r} at position {pos} in {sentence!r}; valid vocabulary: "
            + ", ".join(VOCAB[1:])
        )


def parse(sentence: str) -> Constraint:
    """Compile a sentence into its :class:`Constraint`.

    Checks run in order, each failing fast: type (``TypeError``), length in characters,
    non-ASCII characters, emptiness, length in words, unknown words (listing the vocabulary),
    a number its clause cannot take (negative, fractional, out of range or signed, with the
    range allowed), then grammar: the first word where it fails, with its 1-based position and
    what was expected there (all ``ValueError``).
    """
    words = normalize(sentence)
    if not words:
        raise ValueError(f"empty constraint {sentence!r}: expected e.g. 'avoid lava'")
    if len(words) > MAX_LEN:
        raise ValueError(f"constraint too long: {len(words)} words (at most {MAX_LEN})")
    _check_words(words, sentence)
    fail = Failure()
    parses = _SENTENCE(words, 0, fail)
    done = [v for v, j in parses if j == len(words)]
    for _, j in parses:  # a whole sentence followed by more words
        if j < len(words):
            fail.note(j, "the end of the sentence (at most two clauses)")
    if done:
        # Distinct parses always agree in meaning (tests check it); keep the first.
        return Constraint(clauses=done[0], sentence=" ".join(words))
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


def parses(sentence: str) -> list[tuple[Clause, ...]]:
    """Every reading of a valid sentence as clauses (``parse`` keeps the first; all readings
    of a sentence mean the same, which the tests check on every table row)."""
    words = normalize(sentence)
    return [v for v, j in _SENTENCE(words, 0, Failure()) if j == len(words)]


def _ends_clause(words: list[str], pos: int) -> bool:
    """Whether a whole first clause ends exactly at ``pos`` (so "and" may follow)."""
    if "and" in words[:pos]:
        return False
    return any(j == pos for _, j in _CLAUSE(words, 0, Failure()))


# --------------------------------------------------------------------------------------
# Token ids
# --------------------------------------------------------------------------------------


def tokenize(sentence: str, max_len: int = MAX_LEN) -> np.ndarray:
    """Token ids of a valid sentence: int32 ``(max_len,)``, right-padded with 0.

    The sentence is parsed first, so invalid sentences raise as in :func:`parse`; one with more
    than ``max_len`` words raises ``ValueError``. A sentence table's
    :meth:`~jaxgrid.sentences.SentenceTable.tokenize` also checks its vocabulary.
    """
    parse(sentence)
    words = normalize(sentence)
    if len(words) > max_len:
        raise ValueError(f"{sentence!r} has {len(words)} words, more than {max_len} token ids")
    ids = np.zeros((max_len,), np.int32)
    ids[: len(words)] = [_WORD_TO_ID[w] for w in words]
    return ids


def detokenize(ids: Any, vocab: Sequence[str] = VOCAB) -> str:
    """Words of a 1-D sequence of token ids (list, numpy or JAX array), up to the first pad;
    ``vocab`` maps ids to words (the whole language's by default)."""
    arr = np.asarray(ids)
    if arr.ndim != 1:
        raise ValueError(f"detokenize expects a 1-D sequence of ids, got shape {arr.shape}")
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        raise ValueError(f"token ids must be integers, got dtype {arr.dtype}")
    words = []
    for i in arr.tolist():
        if i == 0:
            break
        if not 0 < i < len(vocab):
            raise ValueError(f"token id {i} out of range [0, {len(vocab)})")
        words.append(vocab[i])
    return " ".join(words)


def sentence_lengths(tokens: Any) -> Any:
    """int32 (...,): the number of real tokens of right-padded id rows (..., L).

    The position of the last non-pad token, so a sentence encoder that stops there reads every
    real word and no padding; an all-pad row has length 0.
    """
    tokens = jnp.asarray(tokens)
    pos = jnp.arange(1, tokens.shape[-1] + 1, dtype=jnp.int32)
    return jnp.max(jnp.where(tokens != VOCAB.index(PAD), pos, 0), -1)


def sentence_index(tokens: Any, table: Any) -> Any:
    """Row of ``table`` (K, L) equal to each row of ``tokens`` (B, L), as int32 (B,).

    With numpy inputs a row found nowhere in the table raises ``ValueError`` naming the
    sentence. With JAX arrays (also under ``jit``, where nothing can raise) such a row gets
    -1: callers that gather with it must mask it (the checker turns it into NaN).
    """
    if isinstance(tokens, np.ndarray) and isinstance(table, np.ndarray):
        match = np.all(tokens[:, None, :] == table[None, :, :], axis=-1)
        missing = ~match.any(axis=-1)
        if missing.any():
            row = tokens[int(np.argmax(missing))]
            raise ValueError(f"sentence {detokenize(row)!r} is not in the sentence table")
        return np.argmax(match, axis=-1).astype(np.int32)
    match = jnp.all(tokens[:, None, :] == table[None, :, :], axis=-1)
    return jnp.where(match.any(axis=-1), jnp.argmax(match, axis=-1), -1).astype(jnp.int32)
