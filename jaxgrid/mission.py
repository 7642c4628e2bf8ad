"""MiniGrid's mission strings as fixed-length token ids, and back to text.

BabyAI-style agents read the mission as words. Every level here states MiniGrid's mission
for the episode through :meth:`jaxgrid.environment.Environment.mission`: an int32
``(MAX_WORDS,)`` array of ids in :data:`WORDS`, padded with ``0``, computed under ``jit`` and
``vmap`` from the state (the target's colour and type, Fetch's phrasing, ...).
:func:`decode` turns ids back into MiniGrid's exact string, comma included;
:func:`encode` does the reverse on the host.

Templates name their slots by role: ``{...colour}`` slots take a colour index
(:data:`jaxgrid.constants.COLOR_NAMES`), ``{...kind}`` slots an object index
(:data:`jaxgrid.constants.OBJECT_NAMES`), e.g. ``fill("pick up the {colour} {kind}",
colour=c, kind=k)``.

The vocabulary holds every word of MiniGrid 3.2.0's missions; it only grows, by appending,
so saved token ids keep their meaning.
"""

from __future__ import annotations

import functools
import re

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrid import grid as G
from jaxgrid.constants import COLOR_NAMES, OBJECT_NAMES

PAD, UNK = 0, 1
# fmt: off
WORDS: tuple[str, ...] = (
    "<pad>", "<unk>", ",",
    # colours and object types, so that a slot's id is a table lookup
    *COLOR_NAMES, *OBJECT_NAMES,
    # the fixed words of every MiniGrid 3.2.0 mission
    "a", "and", "at", "avoid", "end", "fetch", "find", "from", "get", "go", "hallway",
    "matching", "must", "near", "object", "of", "open", "opening", "pick", "put", "reach",
    "room", "rooms", "square", "the", "then", "to", "traverse", "unlock", "up", "use", "you",
)
# fmt: on
WORD_TO_ID = {word: i for i, word in enumerate(WORDS)}
MAX_WORDS = 24  # LockedRoom's mission, the longest, has 20 tokens
VOCAB_SIZE = len(WORDS)
COLOUR_IDS = np.array([WORD_TO_ID[c] for c in COLOR_NAMES], np.int32)
KIND_IDS = np.array([WORD_TO_ID[k] for k in OBJECT_NAMES], np.int32)


def tokenize(text: str) -> list[str]:
    """MiniGrid mission text as words; a comma is a word of its own."""
    return text.replace(",", " , ").split()


def encode(text: str, *, strict: bool = True) -> np.ndarray:
    """int32 ``(MAX_WORDS,)`` ids of ``text``, padded with ``PAD``.

    A word outside :data:`WORDS` raises ``ValueError`` naming it (``strict=False`` maps it to
    ``UNK``, for missions of custom MiniGrid envs); so does a text over ``MAX_WORDS`` words.
    """
    words = tokenize(text)
    if len(words) > MAX_WORDS:
        raise ValueError(f"mission {text!r} has {len(words)} words, more than {MAX_WORDS}")
    unknown = [w for w in words if w not in WORD_TO_ID]
    if unknown and strict:
        raise ValueError(f"mission word {unknown[0]!r} (in {text!r}) is not in the vocabulary")
    ids = np.full(MAX_WORDS, PAD, np.int32)
    ids[: len(words)] = [WORD_TO_ID.get(w, UNK) for w in words]
    return ids


def decode(ids) -> str:
    """The text of one id array (padding dropped): MiniGrid's mission string."""
    ids = np.asarray(ids)
    if ids.ndim != 1:
        raise ValueError(f"decode takes one mission, an id array of shape (n,); got {ids.shape}")
    if ids.size and (ids.min() < 0 or ids.max() >= VOCAB_SIZE):
        raise ValueError(f"mission ids must lie in 0..{VOCAB_SIZE - 1}, got {ids.tolist()}")
    return " ".join(WORDS[i] for i in ids if i != PAD).replace(" ,", ",")


@functools.cache
def _parts(template: str) -> tuple[tuple[str, int | str], ...]:
    """The template's words: ``("word", id)`` or ``("slot", name)``, checked once."""
    parts = []
    for word in tokenize(template):
        match = re.fullmatch(r"\{(\w+)\}", word)
        if match:
            name = match.group(1)
            if not name.endswith(("colour", "kind")):
                raise ValueError(
                    f"mission slot {{{name}}} in {template!r} must end in 'colour' or 'kind'"
                )
            parts.append(("slot", name))
        elif any(c in word for c in "{}"):
            raise ValueError(f"malformed mission slot {word!r} in {template!r}")
        else:
            encode(word)  # an unknown word raises, naming it
            parts.append(("word", WORD_TO_ID[word]))
    if len(parts) > MAX_WORDS:
        raise ValueError(f"mission {template!r} has {len(parts)} words, more than {MAX_WORDS}")
    return tuple(parts)


def fill(template: str, **slots) -> jax.Array:
    """int32 ``(MAX_WORDS,)`` ids of ``template`` with its slots filled (traced ints allowed).

    A slot named in the template and missing from ``slots`` (or the reverse) raises
    ``ValueError`` naming it.
    """
    parts = _parts(template)
    names = {value for what, value in parts if what == "slot"}
    if names != set(slots):
        missing = sorted(names - set(slots)) or sorted(set(slots) - names)
        raise ValueError(f"mission {template!r}: slot {missing[0]!r} missing or unused")
    ids = []
    for what, value in parts:
        if what == "word":
            ids.append(jnp.int32(value))
        else:
            table = COLOUR_IDS if value.endswith("colour") else KIND_IDS
            ids.append(G.select(jnp.asarray(slots[value], jnp.int32), table))
    ids += [jnp.int32(PAD)] * (MAX_WORDS - len(ids))
    return jnp.stack(ids).astype(jnp.int32)


def choose(index, missions) -> jax.Array:
    """The ``index``-th of several filled missions (int32 ``(k, MAX_WORDS)``)."""
    return G.select(index, jnp.asarray(missions)).astype(jnp.int32)
