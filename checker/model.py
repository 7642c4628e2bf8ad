"""The window checker: the network (:class:`Checker`) and a trained one (:class:`TrainedChecker`),
which answers: is the agent about to break the constraint?

Inputs: a window of the last ``n`` egocentric observations, uint8 ``(B, n, V, V, 3)`` MiniGrid
encodings ordered oldest -> newest (the all-zero frame, "unseen" everywhere, pads windows at
the start of an episode), and the constraint's token ids, int32 ``(B, L)`` right-padded with
the id of :data:`jaxgrid.language.PAD`. Output: one logit per row that a violation is about to
happen (the label's exact meaning is fixed by the data, see :mod:`checker.data.labels`).

Architecture (the paper's, sizes in :class:`CheckerConfig`):

* language module (:meth:`Checker.encode_language`): ``Embed(word_dim=32)`` -> ``GRU(128)``
  run over the real tokens only; the sentence code is the GRU state after the last non-pad
  token (padding never touches it, so any padded length gives the same code);
* trajectory module, per state (:meth:`Checker.embed_states`): each cell's
  ``(object, colour, state)`` triple is embedded by three lookup tables whose rows are
  summed, then a 3x3 ``Conv2D`` (VALID, ReLU) and a ``Dense`` give a ``state_dim=64`` state code;
* over the window (:meth:`Checker.classify`): a ``Conv1D`` (kernel 3, ReLU) over the ``n``
  state codes, flattened (so the newest frame keeps its place), concatenated with the
  sentence code, then an MLP (ReLU) -> one logit.

Why cells are embedded by lookup rather than fed as raw integers: the three channels are
*categorical*. As numbers, "red" (0) would sit next to "green" (1) and "door" (4) halfway
between "floor" (3) and "key" (5), so a convolution would have to undo an arbitrary order
before it could tell a red door from a blue one, which is exactly what the checker must do
to compare a door with the colour named in the sentence. A lookup gives every object, colour
and door state its own learned vector; summing the three lookups equals a linear layer on the
concatenated one-hot codes, at the cost of a gather. The door *state* matters too (an agent
can only enter an open door), and lookups keep "open" (0) distinct from "unseen"-padding,
whose cell is ``(0, 0, 0)``.

The trajectory module runs every env step for every environment inside PPO, so it is kept
small: 16-d cell codes, one 3x3 convolution with 16 channels and VALID padding (5x5 -> 3x3;
every cell still reaches the state code) and a 64-d state code cost about 30k multiply-adds
per frame. VALID rather than SAME padding, because the padded convolution is much slower on
XLA:CPU (figures in ``docs/decisions.md``).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import language
from jaxgrid.constants import COLOR_NAMES, OBJECT_NAMES, STATE_NAMES

NUM_OBJECTS = len(OBJECT_NAMES)  # 11
NUM_COLOURS = len(COLOR_NAMES)  # 6
NUM_STATES = len(STATE_NAMES)  # 3


@dataclasses.dataclass(frozen=True)
class CheckerConfig:
    """Static sizes of the checker. Every field is validated in ``__post_init__``.

    Attributes:
        window: number ``n`` of observations per window.
        view_size: side ``V`` of the egocentric view.
        max_len: token ids per constraint (``jaxgrid.language.MAX_LEN``).
        vocab_size: number of token ids (``jaxgrid.language.vocab_size()``).
        word_dim: word embedding size (paper: 32).
        gru_dim: GRU state size, the sentence code (paper: 128).
        state_dim: per-state embedding size (paper: 64).
        cell_dim: size of each cell's (object + colour + state) embedding.
        conv_channels: output channels of the per-state 3x3 convolution.
        temporal_channels: output channels of the Conv1D over the window.
        temporal_kernel: kernel size of the Conv1D over the window (SAME padding).
        mlp_dim: hidden width of the final MLP.
        mlp_layers: hidden layers of the final MLP.
    """

    window: int = 5
    view_size: int = 5
    max_len: int = language.MAX_LEN
    vocab_size: int = language.vocab_size()
    word_dim: int = 32
    gru_dim: int = 128
    state_dim: int = 64
    cell_dim: int = 16
    conv_channels: int = 16
    temporal_channels: int = 64
    temporal_kernel: int = 3
    mlp_dim: int = 128
    mlp_layers: int = 2

    def __post_init__(self):
        limits = {"window": (1, 64), "view_size": (1, 31), "temporal_kernel": (1, 64)}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if not isinstance(value, int) or isinstance(value, bool):
                raise ValueError(
                    f"CheckerConfig.{f.name} must be an int, got {type(value).__name__} {value!r}"
                )
            lo, hi = limits.get(f.name, (1, 1 << 16))
            if not lo <= value <= hi:
                raise ValueError(f"CheckerConfig.{f.name} must be in [{lo}, {hi}], got {value}")
        if self.view_size % 2 == 0:
            raise ValueError(f"CheckerConfig.view_size must be odd, got {self.view_size}")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> CheckerConfig:
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ValueError(f"unknown CheckerConfig field(s) {unknown}; fields: {sorted(names)}")
        return cls(**d)


class Checker(nn.Module):
    """Window of observations + constraint tokens -> violation logit (see the module docs)."""

    config: CheckerConfig

    def setup(self):
        c = self.config
        self.word_embed = nn.Embed(c.vocab_size, c.word_dim, name="word_embed")
        self.gru = nn.RNN(nn.GRUCell(c.gru_dim), name="gru")
        self.object_embed = nn.Embed(NUM_OBJECTS, c.cell_dim, name="object_embed")
        self.colour_embed = nn.Embed(NUM_COLOURS, c.cell_dim, name="colour_embed")
        self.door_state_embed = nn.Embed(NUM_STATES, c.cell_dim, name="door_state_embed")
        self.cell_conv = nn.Conv(c.conv_channels, (3, 3), padding="VALID", name="cell_conv")
        self.state_dense = nn.Dense(c.state_dim, name="state_dense")
        self.temporal_conv = nn.Conv(
            c.temporal_channels, (c.temporal_kernel,), padding="SAME", name="temporal_conv"
        )
        self.hidden = [nn.Dense(c.mlp_dim, name=f"mlp_{i}") for i in range(c.mlp_layers)]
        self.head = nn.Dense(1, name="head")

    def __call__(self, windows: jax.Array, tokens: jax.Array) -> jax.Array:
        """uint8 ``(B, n, V, V, 3)`` windows, int32 ``(B, L)`` tokens -> float32 ``(B,)``."""
        return self.classify(self.embed_states(windows), self.encode_language(tokens))

    def encode_language(self, tokens: jax.Array) -> jax.Array:
        """int ``(B, L)`` ids -> float32 ``(B, gru_dim)``: the GRU state at the last real token."""
        return encode_sentence(self.word_embed, self.gru, tokens)

    def embed_states(self, frames: jax.Array) -> jax.Array:
        """uint8 ``(..., V, V, 3)`` frames -> float32 ``(..., state_dim)``."""
        v = self.config.view_size
        if frames.shape[-3:] != (v, v, 3):
            raise ValueError(f"frames must end in ({v}, {v}, 3), got shape {frames.shape}")
        lead = frames.shape[:-3]
        x = jnp.asarray(frames, jnp.int32).reshape((-1, v, v, 3))
        cells = embed_cells(x, self.object_embed, self.colour_embed, self.door_state_embed)
        h = nn.relu(self.cell_conv(cells))
        h = nn.relu(self.state_dense(h.reshape((h.shape[0], -1))))
        return h.reshape(lead + (self.config.state_dim,))

    def classify(self, state_emb: jax.Array, lang: jax.Array) -> jax.Array:
        """``(B, n, state_dim)`` state codes, ``(B, gru_dim)`` sentence codes -> logits ``(B,)``."""
        h = nn.relu(self.temporal_conv(state_emb))
        h = jnp.concatenate([h.reshape((h.shape[0], -1)), lang], axis=-1)
        for layer in self.hidden:
            h = nn.relu(layer(h))
        return self.head(h)[..., 0].astype(jnp.float32)


def candidate_logits(params, config: CheckerConfig, past, cand, lang) -> jax.Array:
    """Logits ``(E, A)`` of the windows ``past`` + each candidate frame, as
    :meth:`Checker.classify` of ``concatenate([past, cand[:, a:a+1]], 1)`` gives them.

    ``past`` (E, n - 1, state_dim) are the window's older frame codes, shared by an env's
    ``A`` candidates ``cand`` (E, A, state_dim), ``lang`` (E, gru_dim) its sentence codes.
    A candidate reaches only the last few outputs of the temporal convolution and their rows
    of the first MLP layer, so everything else is computed once per env, not once per
    candidate: a shield scores every action of every env on every step, and this is most of
    its cost.
    """
    p, n = params["params"], config.window
    k = config.temporal_kernel
    low = (k - 1) // 2  # SAME padding's left side (lax's rule)
    first = max(n - 1 - (k - 1 - low), 0)  # the first output a candidate reaches
    # The candidate's contribution to outputs first..n-1: kernel tap n-1-i+low of output i.
    taps = p["temporal_conv"]["kernel"][np.array([n - 1 - i + low for i in range(first, n)])]
    module = Checker(config)
    blank = jnp.concatenate([past, jnp.zeros_like(cand[:, :1])], axis=1)  # candidate: 0
    base = module.apply(params, blank, method=lambda m, x: m.temporal_conv(x))  # (E, n, C)
    reach = jnp.einsum("ead,mdc->eamc", cand, taps) + base[:, None, first:]
    c = base.shape[-1]
    w0 = p["mlp_0"]["kernel"]
    shared = jnp.concatenate([nn.relu(base[:, :first]).reshape(base.shape[0], -1), lang], -1)
    shared = shared @ jnp.concatenate([w0[: first * c], w0[n * c :]]) + p["mlp_0"]["bias"]
    h = nn.relu(nn.relu(reach).reshape(reach.shape[:2] + (-1,)) @ w0[first * c : n * c]
                + shared[:, None])  # fmt: skip
    for i in range(1, config.mlp_layers):
        layer = p[f"mlp_{i}"]
        h = nn.relu(h @ layer["kernel"] + layer["bias"])
    return (h @ p["head"]["kernel"] + p["head"]["bias"])[..., 0].astype(jnp.float32)


def embed_cells(x: jax.Array, objects: nn.Embed, colours: nn.Embed, states: nn.Embed):
    """int ``(..., 3)`` MiniGrid cells -> the sum of their three lookups ``(..., cell_dim)``.

    Codes are clipped so an out-of-range one cannot index past a table (XLA would clamp
    anyway). Shared by the window checker and the checker with memory.
    """
    return (
        objects(jnp.clip(x[..., 0], 0, NUM_OBJECTS - 1))
        + colours(jnp.clip(x[..., 1], 0, NUM_COLOURS - 1))
        + states(jnp.clip(x[..., 2], 0, NUM_STATES - 1))
    )


def encode_sentence(embed: nn.Embed, gru: nn.RNN, tokens: jax.Array) -> jax.Array:
    """The sentence code of right-padded token ids (..., L): ``gru``'s carry after the last
    real word (:func:`jaxgrid.language.sentence_lengths`), so padding never touches it.

    The one sentence encoding of the repository: the checker and the policy call it with
    their own ``Embed`` and ``RNN(GRUCell)`` submodules (``return_carry=False`` RNNs).
    """
    tokens = jnp.asarray(tokens, jnp.int32)
    lengths = language.sentence_lengths(tokens)
    return gru(embed(tokens), seq_lengths=lengths, return_carry=True)[0]


def _dummy_inputs(config: CheckerConfig):
    v = config.view_size
    windows = jnp.zeros((1, config.window, v, v, 3), jnp.uint8)
    tokens = jnp.zeros((1, config.max_len), jnp.int32)
    return windows, tokens


def init_params(config: CheckerConfig, key: jax.Array):
    """Fresh parameters of ``Checker(config)`` (dummy batch of one; jitted, since an eager
    Flax init compiles the GRU's scan op by op)."""
    return jax.jit(Checker(config).init)(key, *_dummy_inputs(config))


def params_shape(config: CheckerConfig):
    """The parameter pytree of ``Checker(config)`` as ``jax.ShapeDtypeStruct`` leaves."""
    return jax.eval_shape(Checker(config).init, jax.random.PRNGKey(0), *_dummy_inputs(config))


class TrainedChecker(struct.PyTreeNode):
    """Parameters (the only pytree leaf) + static configuration of a trained window checker,
    a :class:`checker.protocol.CheckerProtocol` whose carry is the embeddings of the last
    ``window - 1`` frames.

    Every method is a thin wrapper over ``Checker(config).apply(params, ...)``, pure and
    jittable; a ``TrainedChecker`` can be passed through ``jax.jit`` as an argument.
    """

    params: Any
    config: CheckerConfig = struct.field(pytree_node=False)
    lookahead: int = struct.field(pytree_node=False, default=1)
    env_id: str = struct.field(pytree_node=False, default="")
    threshold: float = struct.field(pytree_node=False, default=0.5)
    kind = "window"  # what it remembers: the last frames (checker.memory_model's: "memory")
    reads = "window"  # windows of the last frames with their sentence
    language = language  # the sentences its token ids spell
    # A shield asks it about every action (None): from lookahead 1 on, a turn can lead to a
    # state from which a violation is expected; its shield results were measured so.
    shield_actions = None

    def record(self) -> dict:
        """What :func:`checker.store.save` records of it beside its parameters."""
        return {"config": self.config.to_dict(), "lookahead": self.lookahead,
                "env_id": self.env_id, "threshold": self.threshold}  # fmt: skip

    @classmethod
    def from_record(cls, meta: dict, read_params) -> TrainedChecker:
        """The checker of a :meth:`record` ``meta``, its parameters from
        ``read_params(template)`` (:func:`checker.store.load`)."""
        config = CheckerConfig.from_dict(meta["config"])
        return cls(params=read_params(params_shape(config)), config=config,
                   lookahead=int(meta["lookahead"]), env_id=str(meta["env_id"]),
                   threshold=float(meta["threshold"]))  # fmt: skip

    @property
    def module(self) -> Checker:
        return Checker(self.config)

    def logits(self, windows: jax.Array, tokens: jax.Array) -> jax.Array:
        """uint8 ``(B, n, V, V, 3)``, int32 ``(B, L)`` -> float32 logits ``(B,)``."""
        return self.module.apply(self.params, windows, tokens)

    def probs(self, windows: jax.Array, tokens: jax.Array) -> jax.Array:
        """Violation probabilities ``(B,)`` (sigmoid of :meth:`logits`)."""
        return jax.nn.sigmoid(self.logits(windows, tokens))

    def encode_language(self, tokens: jax.Array) -> jax.Array:
        return self.module.apply(self.params, tokens, method=Checker.encode_language)

    def embed_states(self, frames: jax.Array, actions: jax.Array | None = None) -> jax.Array:
        """Frame embeddings; ``actions`` (the memory checker's interface) is unused: the
        window checker reads frames only."""
        del actions
        return self.module.apply(self.params, frames, method=Checker.embed_states)

    def classify(self, state_emb: jax.Array, lang: jax.Array) -> jax.Array:
        return self.module.apply(self.params, state_emb, lang, method=Checker.classify)

    # -- streams: what a learner carries per env (checker.protocol) ---------------------
    def stream_start(self, emb: jax.Array, lang: jax.Array) -> jax.Array:
        """The memory of episodes whose first frames embed to ``emb`` (E, D): the embeddings
        of the last ``window - 1`` frames (E, n - 1, D), blank frames before the first.
        ``lang`` is unused (the window is read with the sentence when it is scored)."""
        del lang
        v = self.config.view_size
        blank = self.embed_states(jnp.zeros((1, v, v, 3), jnp.uint8))
        n = self.config.window
        older = jnp.broadcast_to(blank[:, None], (emb.shape[0], max(n - 2, 0), emb.shape[-1]))
        return jnp.concatenate([older, emb[:, None]], axis=1)[:, max(2 - n, 0) :]

    def stream_step(self, memory: jax.Array, emb: jax.Array, lang: jax.Array):
        """``(logit (E,), memory)``: the violation logit of the window ending at the frame
        embedded as ``emb``, and the memory with that frame in it."""
        window = jnp.concatenate([memory, emb[:, None]], axis=1)
        return self.classify(window, lang), window[:, 1:]

    def candidate_logits(self, memory: jax.Array, emb: jax.Array, lang: jax.Array):
        """Logits ``(E, A)`` of :meth:`stream_step` for each of ``A`` candidate frames
        embedded as ``emb`` (E, A, D), from one memory per env (what a shield asks)."""
        return candidate_logits(self.params, self.config, memory, emb, lang)


def new_checker(
    config: CheckerConfig,
    key: jax.Array,
    *,
    lookahead: int = 1,
    env_id: str = "",
    threshold: float = 0.5,
) -> TrainedChecker:
    """An untrained (freshly initialised) checker."""
    return TrainedChecker(
        params=init_params(config, key),
        config=config,
        lookahead=int(lookahead),
        env_id=str(env_id),
        threshold=float(threshold),
    )
