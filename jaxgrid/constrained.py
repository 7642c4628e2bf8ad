"""What code outside an environment reads of its constraint: its sentence table and tokens."""

from __future__ import annotations

import numpy as np

from jaxgrid.language import PAD, VOCAB
from jaxgrid.sentences import PAPER, SentenceTable

__all__ = ["language_table", "sentence_tokens"]


def language_table(env) -> SentenceTable:
    """The table whose token ids ``env`` observes; the paper's for an env without one, so
    that a model built for it keeps the paper's embedding size."""
    return getattr(env, "language_table", PAPER)


def sentence_tokens(env) -> np.ndarray:
    """int32 ``(K, max_len)`` token ids of every sentence of ``env``'s constraint table (the
    rows it draws from), or one pad row for an env without one, so that code indexing the
    table works unchanged."""
    if not hasattr(env, "constraint_table"):
        return np.full((1, language_table(env).max_len), VOCAB.index(PAD), np.int32)
    return np.asarray(env.constraint_table()["tokens"], np.int32)
