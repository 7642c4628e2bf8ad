"""Actor-critic conditioned on the egocentric observation and the English constraint.

Observation branch: each cell's (object, colour, state) triple is one-hot encoded and mixed
by a 1x1 convolution into ``cell_dim`` features (a learned embedding per field, summed; a
one-hot matmul rather than ``nn.Embed`` because its gradient is a matmul too, where an
embedding's is a scatter, slow on CPU), then 3x3 ``VALID`` Conv2D layers (:class:`PatchConv`)
and a Dense layer.
The agent's direction is appended one-hot.

Language branch: Embed(32) -> GRU(128) over the token ids, read at the last real token
(padding is ignored), as in the paper's checker.

The language branch is exposed separately (:meth:`ActorCritic.encode_language`) because
constraints come from a small fixed set of sentences: the learner encodes that table once
per minibatch and gathers rows, instead of running the GRU for every sample (see
:mod:`agents.train`). :meth:`ActorCritic.__call__` takes the sentence features, not tokens.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from checker.model import encode_sentence
from jaxgrid.constants import COLOR_NAMES, OBJECT_NAMES, STATE_NAMES
from jaxgrid.sentences import PAPER

_SIZES = (len(OBJECT_NAMES), len(COLOR_NAMES), len(STATE_NAMES))


def _ortho(scale: float = 1.0):
    """Flax's orthogonal initializer, computed one key at a time under ``vmap``.

    Same values as ``nn.initializers.orthogonal(scale)``. Under ``vmap`` the QR runs in a
    ``lax.map`` loop (``sequential_vmap``), because batched LAPACK QR calls inside one jitted
    program can hang XLA:CPU (``docs/decisions.md``); it is an initialisation-only cost.
    """
    base = nn.initializers.orthogonal(scale)

    def init(key, shape, dtype=jnp.float32):
        return jax.custom_batching.sequential_vmap(lambda k: base(k, shape, dtype))(key)

    return init


def one_hot_cells(image: jax.Array) -> jax.Array:
    """uint8 (..., V, V, 3) MiniGrid encoding -> float32 (..., V, V, objects+colours+states)."""
    image = image.astype(jnp.int32)
    return jnp.concatenate([jax.nn.one_hot(image[..., i], n) for i, n in enumerate(_SIZES)], -1)


class PatchConv(nn.Module):
    """A 2-D convolution (``VALID``, stride 1) computed as dense matmuls.

    Same parameters and result as ``nn.Conv(features, (k, k), padding="VALID")``. The kernel
    is unrolled through constant 0/1 tensors of tap positions, so the layer is matmuls on
    the flattened input, forward and backward: on XLA:CPU that is faster than a convolution
    inside PPO's minibatch ``lax.scan``. Two forms (``form``):

    - ``"dense"``: one ``(H*W*C, OH*OW*features)`` matrix over the whole view;
    - ``"rows"``: each output row from the ``k`` input rows it reads, concatenated, times one
      ``(k*W*C, OW*features)`` matrix: ``H / k`` times fewer multiply-adds, one copy more.

    ``"auto"`` takes ``"rows"`` for views of 7 rows or more and ``"dense"`` below, the faster
    of the two in a whole PPO update at 7x7 and 5x5 views (figures in ``docs/decisions.md``).
    """

    features: int
    kernel_size: int = 3
    kernel_init: Any = nn.initializers.lecun_normal()
    form: str = "auto"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        k, (h, w, c_in) = self.kernel_size, x.shape[-3:]
        kernel = self.param("kernel", self.kernel_init, (k, k, c_in, self.features))
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        oh, ow = h - k + 1, w - k + 1
        form = ("rows" if h >= 7 else "dense") if self.form == "auto" else self.form
        if form == "dense":
            taps = _conv_taps(h, w, k)  # (k*k, h*w, oh*ow), numpy constant
            dense = jnp.einsum("tqp,tco->qcpo", taps, kernel.reshape(k * k, c_in, self.features))
            dense = dense.reshape(h * w * c_in, oh * ow * self.features)
            y = x.reshape(x.shape[:-3] + (h * w * c_in,)) @ dense
        elif form == "rows":
            # kernel row 0's taps over a k-row input: column j reads input column p + j
            taps = _conv_taps(k, w, k)[:k, :w]  # (k, w, ow), numpy constant
            dense = jnp.einsum("jqp,ijco->iqcpo", taps, kernel)
            dense = dense.reshape(k * w * c_in, ow * self.features)
            rows = x.reshape(x.shape[:-3] + (h, w * c_in))
            y = jnp.concatenate([rows[..., i : i + oh, :] for i in range(k)], -1) @ dense
        else:
            raise ValueError(f"PatchConv.form must be 'auto', 'dense' or 'rows', got {form!r}")
        return y.reshape(x.shape[:-3] + (oh, ow, self.features)) + bias


@functools.cache
def _conv_taps(h: int, w: int, k: int) -> np.ndarray:
    """``taps[t, q, p] = 1`` where kernel tap ``t`` reads input cell ``q`` for output ``p``."""
    oh, ow = h - k + 1, w - k + 1
    taps = np.zeros((k * k, h * w, oh * ow), np.float32)
    for i in range(k):
        for j in range(k):
            for y in range(oh):
                for x in range(ow):
                    taps[i * k + j, (y + i) * w + (x + j), y * ow + x] = 1.0
    return taps


class SentenceEncoder(nn.Module):
    """Embed(word_dim) -> GRU(gru_dim); returns the hidden state after the last real token."""

    vocab_size: int = PAPER.vocab_size
    word_dim: int = 32
    gru_dim: int = 128

    @nn.compact
    def __call__(self, tokens: jax.Array) -> jax.Array:
        embed = nn.Embed(self.vocab_size, self.word_dim)
        rnn = nn.RNN(nn.GRUCell(self.gru_dim, recurrent_kernel_init=_ortho()))
        return encode_sentence(embed, rnn, tokens)


class ActorCritic(nn.Module):
    """Policy logits, value and cost value from observation + projected sentence features.

    Call with ``image`` uint8 (B, V, V, 3), ``direction`` int32 (B,) and ``lang`` float32
    (B, lang_dim) from :meth:`project_language` of :meth:`encode_language`. Returns
    ``(logits (B, A), value (B,), cost_value (B,))``; the cost head is only trained in the
    Lagrangian mode. The sentence modulates the observation features FiLM-style,
    twice: per channel on every cell's features, ``relu(cells * (1 + s) + b)`` broadcast over
    the view as in BabyAI's FiLM, and per unit on the observation features,
    ``tanh(Dense(obs) * (1 + scale) + shift)``, then one more tanh layer. Avoiding *the red
    door* needs the product of "red" in the sentence and "red door ahead" in the view, which
    an additive merge expresses poorly; the per-cell modulation lets the sentence mark the
    forbidden door where it stands, before the convolution; without it agents learn to ignore
    the sentence (``docs/decisions.md``). With ``film_codes`` the sentence also weighs each
    cell's one-hot object, colour and state codes before they are embedded, ``codes * (1 +
    w)``: per-channel scales of 8 summed features can single out one colour only where the
    embedding has set it apart, a weight per code can at once.
    The projection depends on the sentence only, so it is computed once per sentence of the
    table rather than once per sample.

    Sizes are small on purpose: on CPU the network is most of the cost of a PPO update
    (``python -m benchmarks.train_speed --profile``).
    """

    num_actions: int = 7
    cell_dim: int = 8
    conv_channels: Sequence[int] = (16,)
    hidden: int = 64
    word_dim: int = 32
    gru_dim: int = 128
    vocab_size: int = PAPER.vocab_size
    recurrent: bool = False  # a GRU memory between the observation and the heads
    # the sentence also scales each cell's one-hot object, colour and state codes
    film_codes: bool = False
    # the heads read the observation features beside the memory (recurrent only)
    memory_skip: bool = False
    # the observation includes the remaining safety budget (Saute), a float beside the direction
    budget_input: bool = False

    def setup(self):
        relu_init = _ortho(np.sqrt(2))
        self.sentence = SentenceEncoder(
            vocab_size=self.vocab_size, word_dim=self.word_dim, gru_dim=self.gru_dim
        )
        if self.recurrent:
            self.core = nn.GRUCell(self.hidden, recurrent_kernel_init=_ortho())
        self.lang_proj = nn.Dense(self.lang_dim, use_bias=False, kernel_init=_ortho(0.1))
        self.cells = nn.Dense(self.cell_dim, kernel_init=relu_init)
        self.convs = [PatchConv(c, 3, kernel_init=relu_init) for c in self.conv_channels]
        self.obs_proj = nn.Dense(self.hidden, kernel_init=relu_init)
        self.mix = nn.Dense(self.hidden, kernel_init=relu_init)
        self.actor = nn.Dense(self.num_actions, kernel_init=_ortho(0.01))
        self.critic = nn.Dense(1, kernel_init=_ortho(1.0))
        self.cost_critic = nn.Dense(1, kernel_init=_ortho(1.0))

    @property
    def lang_dim(self) -> int:
        """Width of the ``lang`` input: FiLM scales and shifts per cell channel and hidden unit,
        then (``film_codes``) a weight per cell code."""
        return 2 * self.cell_dim + 2 * self.hidden + (sum(_SIZES) if self.film_codes else 0)

    def encode_language(self, tokens: jax.Array) -> jax.Array:
        """(..., L) token ids -> (..., gru_dim) sentence features."""
        return self.sentence(tokens)

    def project_language(self, features: jax.Array) -> jax.Array:
        """(..., gru_dim) sentence features -> (..., lang_dim) FiLM scales and shifts."""
        return self.lang_proj(features)

    @property
    def memory_dim(self) -> int:
        """Width of the recurrent memory (1, a placeholder, without one)."""
        return self.hidden if self.recurrent else 1

    def __call__(self, image, direction, lang, budget=None):
        """``(logits, value, cost_value)`` of a memoryless network."""
        if self.recurrent:
            raise ValueError("a recurrent ActorCritic is called with step(..., memory)")
        logits, value, cost_value, _ = self.step(image, direction, lang, None, budget)
        return logits, value, cost_value

    def step(self, image, direction, lang, memory, budget=None):
        """``(logits, value, cost_value, memory)``: one step, from the memory of the episode's
        previous steps (zeros at its start; (B, :attr:`memory_dim`)). Without recurrence the
        memory passes through unchanged."""
        return self.heads(self.observe(image, direction, lang, budget), memory)

    def observe(self, image, direction, lang, budget=None):
        """The sentence-modulated observation features (B, hidden): everything before the
        memory, so a recurrent update computes it for a whole sequence at once. With
        ``budget_input`` the observation also holds ``budget`` float32 (B,), the remaining
        safety budget (None: all of it, 1)."""
        cell_film, hidden_film, code_film = jnp.split(
            lang, [2 * self.cell_dim, 2 * self.cell_dim + 2 * self.hidden], axis=-1
        )
        c_scale, c_shift = jnp.split(cell_film[..., None, None, :], 2, axis=-1)
        codes = one_hot_cells(image)
        if self.film_codes:  # per sentence, a weight for every object, colour and state
            codes = codes * (1.0 + code_film[..., None, None, :])
        x = nn.relu(self.cells(codes) * (1.0 + c_scale) + c_shift)
        for conv in self.convs:
            x = nn.relu(conv(x))
        x = x.reshape(x.shape[:-3] + (-1,))
        parts = [x, jax.nn.one_hot(direction, 4)]
        if self.budget_input:
            budget = jnp.ones(direction.shape) if budget is None else budget
            parts.append(budget[..., None].astype(x.dtype))
        x = jnp.concatenate(parts, axis=-1)
        scale, shift = jnp.split(hidden_film, 2, axis=-1)
        return jnp.tanh(self.obs_proj(x) * (1.0 + scale) + shift)

    def heads(self, h, memory):
        """``(logits, value, cost_value, memory)`` from :meth:`observe`'s features."""
        if self.recurrent:
            memory = self.remember(self.memory_inputs(h), memory)
        return self.read(h, memory) + (memory,)

    def memory_inputs(self, h):
        """The memory's input terms (..., 3 * hidden) of :meth:`observe`'s features: the GRU's
        reset, update and candidate pre-activations before the memory's share is added. They
        do not depend on the memory, so a recurrent update computes them for a whole sequence
        at once and only :meth:`remember` runs step by step."""
        if self.is_initializing():  # the parameters of flax's GRUCell, under its names
            self.core(jnp.zeros(h.shape[:-1] + (self.hidden,), h.dtype), h)
        core = self.variables["params"]["core"]
        gates = ("ir", "iz", "in")
        kernel = jnp.concatenate([core[g]["kernel"] for g in gates], -1)
        return h @ kernel + jnp.concatenate([core[g]["bias"] for g in gates], -1)

    def remember(self, inputs, memory):
        """The next memory (..., hidden) from :meth:`memory_inputs` and the memory: flax's
        ``GRUCell`` with its three recurrent matmuls as one."""
        core = self.variables["params"]["core"]
        kernel = jnp.concatenate([core[g]["kernel"] for g in ("hr", "hz", "hn")], -1)
        r, z, n = jnp.split(inputs, 3, axis=-1)
        hr, hz, hn = jnp.split(memory @ kernel, 3, axis=-1)
        r, z = nn.sigmoid(r + hr), nn.sigmoid(z + hz)
        n = jnp.tanh(n + r * (hn + core["hn"]["bias"]))
        return (1.0 - z) * n + z * memory

    def read(self, h, memory=None):
        """``(logits, value, cost_value)`` from :meth:`observe`'s features ``h`` and, in a
        recurrent network, the memory after this step: the heads read the memory, and with
        ``memory_skip`` the features beside it, so that what is in view reaches the action
        without passing the GRU's update gate."""
        if self.recurrent:
            h = jnp.concatenate([memory, h], -1) if self.memory_skip else memory
        h = jnp.tanh(self.mix(h))
        return self.actor(h), self.critic(h)[..., 0], self.cost_critic(h)[..., 0]

    def sentence_features(self, tokens: jax.Array) -> jax.Array:
        """Tokens -> the ``lang`` input of :meth:`__call__` (GRU, then projection)."""
        return self.project_language(self.encode_language(tokens))

    def init_all(self, image, direction, tokens):
        """Initialisation path touching every submodule (use as ``method=`` in ``init``)."""
        memory = jnp.zeros(image.shape[:1] + (self.memory_dim,), jnp.float32)
        return self.step(image, direction, self.sentence_features(tokens), memory)


def table_features(network: ActorCritic, params, tokens: jax.Array | None) -> jax.Array:
    """The ``lang`` input of every sentence of a table (K, L) -> (K, lang_dim).

    ``tokens`` None (an env without constraints) gives one row of zeros. The learner calls
    this once per rollout and once per minibatch, so the GRU runs per sentence, not per sample.
    """
    if tokens is None:
        return jnp.zeros((1, network.lang_dim), jnp.float32)
    return network.apply(params, tokens, method=ActorCritic.sentence_features)


def apply_policy(
    network: ActorCritic, params, lang_table, image, direction, sentence, memory, budget=None
):
    """``network.step`` on a batch whose sentences are rows ``sentence`` (B,) of
    ``lang_table`` (and, for a Saute policy, remaining budgets ``budget`` (B,)):
    ``(logits, value, cost_value, memory)``.

    The row is selected by a one-hot matmul rather than a gather: its gradient is a matmul,
    not a scatter (slow on CPU).
    """
    lang = table_rows(lang_table, sentence)
    return network.apply(params, image, direction, lang, memory, budget, method=ActorCritic.step)


def table_rows(lang_table: jax.Array, sentence: jax.Array) -> jax.Array:
    """Rows ``sentence`` (B,) of ``lang_table`` (K, D), selected by a one-hot matmul."""
    return jax.nn.one_hot(sentence, lang_table.shape[0], dtype=lang_table.dtype) @ lang_table


VALUE_HEADS = ("critic", "cost_critic")  # the modules of the value and cost-value heads


def value_heads_only(grads):
    """Gradients of an :class:`ActorCritic`'s parameters with zeros outside
    :data:`VALUE_HEADS`: a step on them fits the values without moving the policy (CPO's
    value fitting, after its trust-region step)."""
    return {
        "params": {
            name: tree if name in VALUE_HEADS else jax.tree.map(jnp.zeros_like, tree)
            for name, tree in grads["params"].items()
        }
    }


def start_memory(network: ActorCritic, batch: int) -> jax.Array:
    """float32 (batch, memory_dim) zeros: the memory at an episode's start."""
    return jnp.zeros((batch, network.memory_dim), jnp.float32)
