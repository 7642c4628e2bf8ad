"""The structured constraint language of Prakash et al. (2020), its tokenizer and parser.

An agent is told, in English, what it must not do: "do not go through the red door and
stay away from lava". This module fixes the grammar that generates every such sentence,
the vocabulary and token ids fed to the constraint checker, a parser that compiles a
sentence into its meaning (:class:`Constraint`: the forbidden door colours and whether
lava is forbidden), and a deterministic held-out split of (template, colour) combinations
for measuring compositional generalisation. The arrays of :func:`combination_table` are what
a jitted constraint sampler indexes into; :func:`sentence_table` and :func:`sentence_index`
let models encode each distinct sentence once and gather rows.

Grammar
-------
::

    SENTENCE    := DOOR_CLAUSE | DOOR_CLAUSE "and" LAVA_CLAUSE
    COLOUR      := "red" | "green" | "blue" | "purple" | "yellow" | "grey"

Every sentence names exactly one door colour; there are no lava-only sentences (the paper
has none) and the conjunction is always door clause first, lava clause second. A
*template* is one door clause, optionally joined by "and" to one lava clause, so there are
7 door-only templates and 7 x 4 = 28 conjunction templates, 35 in all.

=====  ========================================  ==========  ===========================
 id    door clause (C = COLOUR)                  paper type   family
=====  ========================================  ==========  ===========================
 0     do not use the C door                     1           "use" verbs
 1     do not go through the C door              2           movement verbs
 2     no C door                                 3           short form (no article)
 3     avoid the C door                          2           movement verbs
 4     avoid C door                              3           short form (no article)
 5     never use the C door                      1           "use" verbs
 6     stay away from the C door                 2           movement verbs
=====  ========================================  ==========  ===========================

=====  ========================================  =========================================
 id    lava clause                               conjunction paper type
=====  ========================================  =========================================
 0     stay away from lava                       4 (long lava clause)
 1     no lava                                   5 (short lava clause)
 2     avoid lava                                5 (short lava clause)
 3     do not touch the lava                     4 (long lava clause)
=====  ========================================  =========================================

Template ids: door-only template ``d`` has id ``d`` (0-6); the conjunction of door clause
``d`` and lava clause ``l`` has id ``7 + 4 * d + l`` (7-34). Paper types 1-3 are door-only
(the door clause's family), 4-5 door + lava (decided by the lava clause alone). The paper's
Table 1 examples map as: "do not use the red door" -> type 1, "do not go through the blue
door" -> 2, "no yellow door" -> 3, "do not go through the red door and stay away from
lava" -> 4, "avoid blue door and no lava" -> 5.

Colours
-------
``COLOUR`` ranges over all six MiniGrid colours, so any MiniGrid door can be described
(e.g. an env converted with ``from_minigrid``). The scenarios only use the five
non-green :data:`DOOR_COLOURS` (green is the goal's colour), and only those five appear in
:func:`split_combinations` and :func:`combination_table`. "green" is therefore a valid
word that the checker never sees in training.

Normalisation
-------------
Case is ignored, every ASCII character other than a letter or digit (punctuation, tabs,
newlines) separates words, and runs of separators collapse, so "Do NOT use the red door!"
and "do not use the red door" are the same sentence. A numeral keeps its sign, decimal point
and digit groups ("-1", "+2", "1.5" and "1,000" are one word each), so that a number is never
read as another; this grammar has no numbers, so any numeral is an unknown word. Non-ASCII
characters are rejected.

Held-out split
--------------
The split holds out seven (door clause, colour) *phrases*, one per door clause
(:data:`HELDOUT_DOOR_PHRASES`). A (template, colour) combination is held out iff its door
clause with that colour is one of them, so a held-out phrase such as "never use the blue
door" never occurs in any training sentence, while "never use the red door" and "avoid
the blue door" do. That is exactly 20% of the combinations
(35 of 175, or 7 of 35 door-only ones); every template keeps four colours and every colour
appears in training, and the paper's Table 1 examples are all training combinations.
"""

from __future__ import annotations

import dataclasses
import functools
import re
from collections.abc import Iterable, Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

from jaxgrid.constants import COLOR_NAMES, COLOR_TO_IDX

__all__ = [
    "COLOURS",
    "DOOR_CLAUSES",
    "DOOR_COLOURS",
    "HELDOUT_DOOR_PHRASES",
    "LAVA_CLAUSES",
    "MAX_CHARS",
    "MAX_LEN",
    "NUM_TEMPLATES",
    "PAD",
    "TEMPLATES",
    "VOCAB",
    "Constraint",
    "Template",
    "combination_table",
    "detokenize",
    "normalize",
    "parse",
    "render",
    "split_combinations",
    "tokenize",
    "tokenize_batch",
    "vocab_size",
]

# --------------------------------------------------------------------------------------
# Fixed tables
# --------------------------------------------------------------------------------------

#: Colours the grammar accepts, in MiniGrid index order (red 0, green 1, ..., grey 5).
COLOURS: tuple[str, ...] = tuple(COLOR_NAMES)
#: Door colours used by the scenarios: the five non-green colours, in MiniGrid order.
DOOR_COLOURS: tuple[str, ...] = ("red", "blue", "purple", "yellow", "grey")

PAD = "<pad>"
#: The vocabulary; a word's token id is its index. Append-only: ids must stay stable.
VOCAB: tuple[str, ...] = (
    PAD,
    # colours, MiniGrid order
    "red", "green", "blue", "purple", "yellow", "grey",
    # nouns and the conjunction
    "door", "lava", "and",
    # function words and verbs
    "do", "not", "use", "go", "through", "the",
    "no", "avoid", "never", "stay", "away", "from", "touch",
)  # fmt: skip
_WORD_TO_ID = {w: i for i, w in enumerate(VOCAB)}

_SLOT = "{colour}"  # the colour slot inside a clause pattern
# A word: a numeral with its sign (spaces after the sign allowed: "- 2" is still negative),
# decimal point and digit groups, when no letter or digit follows it ("1st" is an ordinary
# word); else a run of letters and digits.
_WORD = re.compile(r"(?:[+-]\s*)?\d+(?:[.,]\d+)*(?![a-z0-9])|[a-z0-9]+")
_SPACE = re.compile(r"\s+")

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

#: Longest sentence in tokens: "do not go through the C door and do not touch the lava".
MAX_LEN: int = 13
#: Inputs longer than this many characters are rejected before any other processing.
MAX_CHARS: int = 200

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
    """One sentence template: a door clause, optionally "and" a lava clause.

    Attributes:
        id: template id (0-6 door-only, 7-34 conjunctions; see the module docstring).
        text: the pattern, with ``{colour}`` where the door colour goes.
        has_door: whether the template forbids a door (always True in this grammar).
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


#: All templates, indexed by id.
TEMPLATES: tuple[Template, ...] = _build_templates()
NUM_TEMPLATES: int = len(TEMPLATES)


@dataclasses.dataclass(frozen=True)
class Constraint:
    """The meaning of a sentence: what the agent must never enter.

    Attributes:
        colour: the door colour the sentence names.
        forbidden_door_colours: colours of the doors the agent must not enter (one colour).
        forbids_lava: whether entering lava is a violation.
        template_id: id of the matched template in :data:`TEMPLATES`.
        paper_type: the paper's constraint type (1-5).
    """

    colour: str
    forbidden_door_colours: frozenset[str]
    forbids_lava: bool
    template_id: int
    paper_type: int

    @property
    def colour_index(self) -> int:
        """MiniGrid colour index of :attr:`colour` (red 0, green 1, blue 2, ...)."""
        return COLOR_TO_IDX[self.colour]

    @property
    def sentence(self) -> str:
        """The canonical sentence of this constraint (lower case, single spaces)."""
        return render(self.template_id, self.colour)


# --------------------------------------------------------------------------------------
# Parser: a word trie over the templates, with the colour slot as one edge
# --------------------------------------------------------------------------------------


@dataclasses.dataclass
class _Node:
    children: dict[str, _Node] = dataclasses.field(default_factory=dict)
    template_id: int | None = None  # set where a complete sentence may end


def _build_trie() -> _Node:
    root = _Node()
    for t in TEMPLATES:
        node = root
        for w in t.words:
            node = node.children.setdefault(w, _Node())
        assert node.template_id is None, f"duplicate template {t.text!r}"
        node.template_id = t.id
    return root


_TRIE = _build_trie()
_END = "<end of sentence>"


def _expected(node: _Node) -> list[str]:
    """Human-readable list of what may follow at ``node``."""
    out = []
    for w in node.children:
        out.append(f"a colour ({', '.join(COLOURS)})" if w == _SLOT else repr(w))
    if node.template_id is not None:
        out.append(_END)
    return out


def normalize(sentence: str) -> list[str]:
    """Split a sentence into lower-case words, ignoring punctuation and extra whitespace.

    Every ASCII character that is not a letter or a digit acts as a separator, except the
    sign, decimal point and digit-group commas of a numeral, which stay in its word ("-1",
    "+2", "1.5", "1,000"; "- 2" is "-2"). Raises
    ``TypeError`` for a non-string and ``ValueError`` for input over :data:`MAX_CHARS`
    characters or containing a non-ASCII character. No vocabulary check is done here.
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


def parse(sentence: str) -> Constraint:
    """Compile a sentence into its :class:`Constraint`.

    Checks run in order, each failing fast: type (``TypeError``), length in characters,
    non-ASCII characters, emptiness, length in words, unknown words, then grammar (all
    ``ValueError``). Unknown-word errors name the word and list the vocabulary; grammar
    errors name the first unexpected word, its 1-based position and what was expected.
    """
    words = normalize(sentence)
    if not words:
        raise ValueError(f"empty constraint {sentence!r}: expected e.g. 'do not use the red door'")
    if len(words) > MAX_LEN:
        raise ValueError(
            f"constraint too long: {len(words)} words (the longest valid sentence has "
            f"{MAX_LEN}): {sentence!r}"
        )
    for pos, w in enumerate(words, start=1):
        if w not in _WORD_TO_ID or w == PAD:
            raise ValueError(
                f"unknown word {w!r} at position {pos} in {sentence!r}; valid vocabulary: "
                + ", ".join(VOCAB[1:])
            )

    node, colour = _TRIE, None
    for pos, w in enumerate(words, start=1):
        if w in node.children:
            node = node.children[w]
        elif w in COLOURS and _SLOT in node.children:
            node, colour = node.children[_SLOT], w
        else:
            raise ValueError(
                f"ungrammatical constraint {sentence!r}: unexpected word {w!r} at position "
                f"{pos}; expected {' or '.join(_expected(node))}"
            )
    if node.template_id is None:
        raise ValueError(
            f"incomplete constraint {sentence!r}: it ends after {words[-1]!r} at position "
            f"{len(words)}; expected {' or '.join(_expected(node))}"
        )

    t = TEMPLATES[node.template_id]
    assert colour is not None  # every template has a door clause
    return Constraint(
        colour=colour,
        forbidden_door_colours=frozenset({colour}),
        forbids_lava=t.has_lava,
        template_id=t.id,
        paper_type=t.paper_type,
    )


def render(template_id: int, colour: str) -> str:
    """The canonical sentence of a template with a colour.

    Every template has a door clause, so ``colour`` is required and must be one of
    :data:`COLOURS`.
    """
    if isinstance(template_id, bool) or not isinstance(template_id, (int, np.integer)):
        raise TypeError(f"template_id must be an int, got {type(template_id).__name__}")
    if not 0 <= template_id < NUM_TEMPLATES:
        raise ValueError(f"template_id {template_id} out of range [0, {NUM_TEMPLATES})")
    if colour not in COLOURS:
        raise ValueError(f"colour must be one of {COLOURS}, got {colour!r}")
    return TEMPLATES[int(template_id)].text.replace(_SLOT, colour)


# --------------------------------------------------------------------------------------
# Token ids
# --------------------------------------------------------------------------------------


def vocab_size() -> int:
    """Number of token ids, padding included (the checker's embedding table size)."""
    return len(VOCAB)


def tokenize(sentence: str) -> np.ndarray:
    """Token ids of a valid sentence: int32 ``(MAX_LEN,)``, right-padded with 0.

    The sentence is parsed first, so invalid sentences raise as in :func:`parse`.
    """
    parse(sentence)
    ids = np.zeros((MAX_LEN,), dtype=np.int32)
    words = normalize(sentence)
    ids[: len(words)] = [_WORD_TO_ID[w] for w in words]
    return ids


def tokenize_batch(sentences: Iterable[str]) -> np.ndarray:
    """Stack :func:`tokenize` over sentences: int32 ``(N, MAX_LEN)``."""
    rows = [tokenize(s) for s in sentences]
    return np.stack(rows) if rows else np.zeros((0, MAX_LEN), dtype=np.int32)


def detokenize(ids: Any, vocab: Sequence[str] = VOCAB) -> str:
    """Words of a 1-D sequence of token ids (list, numpy or JAX array), up to the first pad;
    ``vocab`` maps ids to words (this language's by default)."""
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


# --------------------------------------------------------------------------------------
# Held-out split and arrays for a jitted sampler
# --------------------------------------------------------------------------------------


def is_heldout(template_id: int, colour: str) -> bool:
    """Whether (template, colour) belongs to the held-out split (never seen in training)."""
    return (TEMPLATES[template_id].door_clause, colour) in HELDOUT_DOOR_PHRASES


def split_combinations(split: str, include_lava: bool = True) -> list[tuple[int, str]]:
    """(template id, colour) combinations of a split, sorted by template then colour.

    Args:
        split: ``"train"``, ``"heldout"`` or ``"all"``.
        include_lava: include the door + lava templates (False for scenarios without lava).

    Only :data:`DOOR_COLOURS` are used. Raises ``ValueError`` for an unknown split.
    """
    if split not in ("train", "heldout", "all"):
        raise ValueError(f"unknown split {split!r}; expected 'train', 'heldout' or 'all'")
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
        ``tokens`` int32 (K, MAX_LEN); ``template_id``, ``paper_type``, ``door_clause`` and
        ``lava_clause`` (-1 if none) int32 (K,); ``door_colour`` int32 (K,) MiniGrid colour
        index; ``forbids_lava`` bool (K,).

    All values are numeric, so ``jax.tree.map(jnp.asarray, table)`` puts it on device.
    """
    combos = split_combinations(split, include_lava=include_lava)
    rows: Sequence[Template] = [TEMPLATES[t] for t, _ in combos]
    return {
        "tokens": tokenize_batch(render(t, c) for t, c in combos),
        "template_id": np.array([t.id for t in rows], dtype=np.int32),
        "paper_type": np.array([t.paper_type for t in rows], dtype=np.int32),
        "door_clause": np.array([t.door_clause for t in rows], dtype=np.int32),
        "lava_clause": np.array([t.lava_clause for t in rows], dtype=np.int32),
        "door_colour": np.array([COLOR_TO_IDX[c] for _, c in combos], dtype=np.int32),
        "forbids_lava": np.array([t.has_lava for t in rows], dtype=bool),
    }


# --------------------------------------------------------------------------------------
# Sentence tables: constraints come from a small fixed set, so models encode the table once
# and each sample gathers its row.
# --------------------------------------------------------------------------------------
@functools.cache
def _grammar_table() -> np.ndarray:
    rows = [tokenize(render(t.id, c)) for t in TEMPLATES for c in COLOURS]
    return np.stack(rows).astype(np.int32)


def sentence_table(env: Any = None) -> np.ndarray:
    """int32 ``(K, MAX_LEN)`` token ids of every sentence a source can produce.

    ``env`` None: every sentence of the grammar (each template with each of the six colours,
    ``K = 210``; the tokenizer is canonical, so any valid constraint's tokens are one of these
    rows). An env with a ``constraint_table()`` (the scenarios): the sentences of its split.
    Any other env: one pad row, so that code indexing the table works unchanged.
    """
    if env is None:
        return _grammar_table()
    if not hasattr(env, "constraint_table"):
        return np.full((1, MAX_LEN), VOCAB.index(PAD), np.int32)
    return np.asarray(env.constraint_table()["tokens"], np.int32)


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
