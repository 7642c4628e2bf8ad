"""The memory checker: a GRU over the episode's frames, for constraints that count.

The window checker (:mod:`checker.model`) sees the last ``n`` frames, so it cannot know how
often the agent has already stepped on lava, or whether it picked up the key twenty steps
ago. :class:`MemoryChecker` carries a recurrent state through the episode instead:

* each frame is embedded as the window checker embeds it (cell lookups, a 3x3 convolution,
  a dense layer, the cell lookups through the window checker's ``embed_cells``);
* a ``GRUCell(memory_dim)`` reads the frame code concatenated with the sentence code (the
  sentence conditions what is worth remembering); its state is zeroed where an episode
  starts, so a batch of streams from auto-resetting envs is read in one scan;
* an MLP on ``[memory, frame code, sentence code]`` gives one logit per step: will the next
  step violate the constraint (labels "just before", as the paper's)?

With ``MemoryCheckerConfig.actions`` the frame code also reads the action that led into the
frame: a turn and a step forward can show the same cells, and only the step enters one, so a
checker of the step into each frame (``lookahead`` 0) needs it most. A learner knows the
action it took, and a shield the action of each candidate.

:class:`TrainedMemoryChecker` is a trained one (parameters + configuration, one pytree), a
:class:`checker.protocol.CheckerProtocol`.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import flax.linen as nn
import flax.struct as struct
import jax
import jax.numpy as jnp

from checker.model import NUM_COLOURS, NUM_OBJECTS, NUM_STATES, embed_cells, encode_sentence
from checker.protocol import LABEL_LOOKAHEADS, MOVES, NO_ACTION
from jaxgrid import hazard_language as HL

_FLAGS = ("memory", "actions")  # MemoryCheckerConfig's bool fields


@dataclasses.dataclass(frozen=True)
class MemoryCheckerConfig:
    """Sizes of :class:`MemoryChecker` (every field a positive int)."""

    view_size: int = 7
    max_len: int = HL.MAX_LEN
    vocab_size: int = HL.vocab_size()
    word_dim: int = 32
    gru_dim: int = 64  # sentence code
    cell_dim: int = 16
    conv_channels: int = 16
    state_dim: int = 64  # frame code
    memory_dim: int = 128
    mlp_dim: int = 128
    memory: bool = True  # False zeroes the memory at every frame: the memoryless ablation
    # the action that led into each frame is read beside it (a turn and a step forward can
    # show the same cells; only the step enters one)
    actions: bool = False

    def __post_init__(self):
        for name in _FLAGS:
            if not isinstance(getattr(self, name), bool):
                raise ValueError(
                    f"MemoryCheckerConfig.{name} must be a bool, got {getattr(self, name)!r}"
                )
        for f in dataclasses.fields(self):
            if f.name in _FLAGS:
                continue
            value = getattr(self, f.name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"MemoryCheckerConfig.{f.name} must be an int >= 1, got {value!r}")
        if self.view_size < 3 or self.view_size % 2 == 0:
            raise ValueError(
                f"MemoryCheckerConfig.view_size must be odd and >= 3, got {self.view_size}"
            )


class MemoryChecker(nn.Module):
    """Streams of frames, episode starts and sentences -> one violation logit per step."""

    config: MemoryCheckerConfig

    def setup(self):
        c = self.config
        self.word_embed = nn.Embed(c.vocab_size, c.word_dim)
        self.sentence_gru = nn.RNN(nn.GRUCell(c.gru_dim))
        self.object_embed = nn.Embed(NUM_OBJECTS, c.cell_dim)
        self.colour_embed = nn.Embed(NUM_COLOURS, c.cell_dim)
        self.door_state_embed = nn.Embed(NUM_STATES, c.cell_dim)
        self.cell_conv = nn.Conv(c.conv_channels, (3, 3), padding="VALID")
        self.state_dense = nn.Dense(c.state_dim)
        # the frame GRU, scanned over time (axis 1) with one set of parameters
        self.memory = nn.scan(
            _MemoryStep,
            variable_broadcast="params",
            split_rngs={"params": False},
            in_axes=1,
            out_axes=1,
        )(c.memory_dim)
        self.hidden = nn.Dense(c.mlp_dim)
        self.head = nn.Dense(1)

    def __call__(self, frames, starts, tokens, actions=None):
        """uint8 ``(B, T, V, V, 3)`` frames, bool ``(B, T)`` starts (True where a frame is an
        episode's first), int32 ``(B, T, L)`` tokens -> float32 ``(B, T)`` logits. With
        ``config.actions``, int32 ``(B, T)`` ``actions`` led into the frames (:data:`NO_ACTION`
        into a first frame)."""
        b, t = starts.shape
        if not self.config.memory:
            starts = jnp.ones_like(starts)
        codes = self.embed_frames(frames, actions)
        lang = self.encode_language(tokens)
        carry = jnp.zeros((b, self.config.memory_dim), jnp.float32)
        memory = self.read(carry, codes, starts, lang)
        return self.classify(memory, codes, lang)

    def encode_language(self, tokens):
        """int32 ``(..., L)`` tokens -> sentence codes ``(..., gru_dim)``."""
        lead = tokens.shape[:-1]
        flat = tokens.reshape(-1, tokens.shape[-1])
        return encode_sentence(self.word_embed, self.sentence_gru, flat).reshape(lead + (-1,))

    def advance(self, carry, codes, lang):
        """One step of every stream: ``(logit (B,), memory (B, memory_dim))`` after reading
        frame codes ``(B, state_dim)`` with sentence codes ``(B, gru_dim)``. ``carry`` is the
        memory before the frame (zeros before an episode's first)."""
        forget = jnp.full(codes.shape[:1] + (1,), not self.config.memory)  # the ablation
        carry, memory = self.memory(carry, (codes[:, None], forget, lang[:, None]))
        return self.classify(memory[:, 0], codes, lang), carry

    def embed_frames(self, frames, actions=None):
        """Frame codes ``(..., state_dim)`` of frames ``(..., V, V, 3)`` and, with
        ``config.actions``, the actions ``(...)`` that led into them."""
        x = jnp.asarray(frames, jnp.int32)
        lead, v = x.shape[:-3], self.config.view_size
        x = x.reshape((-1, v, v, 3))
        cells = embed_cells(x, self.object_embed, self.colour_embed, self.door_state_embed)
        h = nn.relu(self.cell_conv(cells))
        h = h.reshape((h.shape[0], -1))
        if self.config.actions:
            if actions is None:
                raise ValueError("this memory checker reads the action into each frame: pass "
                                 "actions (MemoryCheckerConfig.actions=True)")  # fmt: skip
            h = jnp.concatenate([h, jax.nn.one_hot(actions.reshape(-1), NO_ACTION + 1)], -1)
        h = nn.relu(self.state_dense(h))
        return h.reshape(lead + (self.config.state_dim,))

    def read(self, carry, codes, starts, lang):
        """The memory after each step, ``(B, T, memory_dim)``, zeroed where ``starts``."""
        _, memory = self.memory(carry, (codes, starts, lang))
        return memory

    def classify(self, memory, codes, lang):
        h = nn.relu(self.hidden(jnp.concatenate([memory, codes, lang], -1)))
        return self.head(h)[..., 0].astype(jnp.float32)


class _MemoryStep(nn.Module):
    """One step of the frame GRU, the carry zeroed at an episode's first frame."""

    features: int

    @nn.compact
    def __call__(self, carry, xs):
        code, start, lang = xs
        carry = jnp.where(start[:, None], 0.0, carry)
        carry, out = nn.GRUCell(self.features, name="cell")(
            carry, jnp.concatenate([code, lang], -1)
        )
        return carry, out


class TrainedMemoryChecker(struct.PyTreeNode):
    """Parameters (the only pytree leaf) + configuration of a trained :class:`MemoryChecker`.

    It is a :class:`checker.protocol.CheckerProtocol` whose carry is the GRU state
    ``(E, memory_dim)``, so PPO carries it per env and its shield scores candidates with it.
    ``lookahead`` is 1 (the step out of each frame violates, the paper's just-before label) or
    0 (the step into it did). Pure and jittable.
    """

    params: Any
    config: MemoryCheckerConfig = struct.field(pytree_node=False)
    env_id: str = struct.field(pytree_node=False, default="")
    threshold: float = struct.field(pytree_node=False, default=0.5)
    lookahead: int = struct.field(pytree_node=False, default=1)
    kind = "memory"
    reads = "stream"  # whole streams of frames, starts, sentences (and actions)
    language = HL  # the sentences its token ids spell

    @property
    def shield_actions(self) -> tuple[int, ...] | None:
        """A checker of the step into each frame can only alarm where a step enters a cell."""
        return MOVES if self.lookahead == 0 else None

    def record(self) -> dict:
        """What :func:`checker.store.save` records of it beside its parameters."""
        return {"config": dataclasses.asdict(self.config), "env_id": self.env_id,
                "threshold": self.threshold, "lookahead": self.lookahead}  # fmt: skip

    @classmethod
    def from_record(cls, meta: dict, read_params) -> TrainedMemoryChecker:
        """The checker of a :meth:`record` ``meta``, its parameters from
        ``read_params(template)`` (:func:`checker.store.load`)."""
        config = MemoryCheckerConfig(**meta["config"])
        template = jax.eval_shape(lambda: init_memory_params(config, jax.random.PRNGKey(0)))
        return cls(params=read_params(template), config=config, env_id=str(meta["env_id"]),
                   threshold=float(meta["threshold"]), lookahead=_lookahead(meta))  # fmt: skip

    @property
    def module(self) -> MemoryChecker:
        return MemoryChecker(self.config)

    def logits(self, frames, starts, tokens, actions=None) -> jax.Array:
        """Streams ``(B, T, ...)`` -> logits ``(B, T)`` (:meth:`MemoryChecker.__call__`)."""
        return self.module.apply(self.params, frames, starts, tokens, actions)

    def embed_states(self, frames: jax.Array, actions: jax.Array | None = None) -> jax.Array:
        """Frame codes; a checker of ``config.actions`` also reads the actions into them."""
        return self.module.apply(self.params, frames, actions, method=MemoryChecker.embed_frames)

    def encode_language(self, tokens: jax.Array) -> jax.Array:
        return self.module.apply(self.params, tokens, method=MemoryChecker.encode_language)

    def stream_step(self, memory: jax.Array, emb: jax.Array, lang: jax.Array):
        """``(logit (E,), memory)`` after reading the frame embedded as ``emb``."""
        return self.module.apply(self.params, memory, emb, lang, method=MemoryChecker.advance)

    def candidate_logits(self, memory: jax.Array, emb: jax.Array, lang: jax.Array):
        """Logits ``(E, A)`` of :meth:`stream_step` for each of ``A`` candidate frames
        embedded as ``emb`` (E, A, D), from one memory per env (what a shield asks)."""
        e, a = emb.shape[:2]
        each = lambda x: jnp.repeat(x, a, axis=0)  # noqa: E731  (row e -> rows e*a .. e*a+a-1)
        flat = emb.reshape((e * a,) + emb.shape[2:])
        return self.stream_step(each(memory), flat, each(lang))[0].reshape(e, a)

    def stream_start(self, emb: jax.Array, lang: jax.Array) -> jax.Array:
        """The memory of episodes whose first frames embed to ``emb``."""
        zeros = jnp.zeros((emb.shape[0], self.config.memory_dim), jnp.float32)
        return self.stream_step(zeros, emb, lang)[1]


def _lookahead(meta: dict) -> int:
    """A record's lookahead: ``lookahead``, or what the ``label`` of a checker saved before the
    name was shared means (none: the just-before label, 1)."""
    if "lookahead" in meta:
        value = meta["lookahead"]
    else:
        value = LABEL_LOOKAHEADS.get(meta.get("label", "next"), meta.get("label"))
    if value not in (0, 1) or isinstance(value, bool):
        raise ValueError(f"a memory checker's lookahead is 0 or 1, its record says {value!r}")
    return int(value)


def new_memory_checker(config: MemoryCheckerConfig, key: jax.Array, **meta):
    """An untrained :class:`TrainedMemoryChecker` (``meta``: ``env_id``, ``threshold``,
    ``lookahead``)."""
    return TrainedMemoryChecker(params=init_memory_params(config, key), config=config, **meta)


def init_memory_params(config: MemoryCheckerConfig, key: jax.Array):
    """Fresh parameters of ``MemoryChecker(config)`` (a dummy stream of one frame)."""
    v, lead = config.view_size, (1, 1)
    frames = jnp.zeros(lead + (v, v, 3), jnp.uint8)
    tokens = jnp.zeros(lead + (config.max_len,), jnp.int32)
    actions = jnp.full(lead, NO_ACTION, jnp.int32) if config.actions else None
    return jax.jit(MemoryChecker(config).init)(key, frames, jnp.ones(lead, bool), tokens, actions)


STREAM_INPUTS = ("frames", "starts", "tokens", "action")


def stream_input_names(config: MemoryCheckerConfig) -> tuple[str, ...]:
    """The names of the model's inputs: frames, starts, tokens (and the actions it reads)."""
    return STREAM_INPUTS if config.actions else STREAM_INPUTS[:3]


def stream_inputs(config: MemoryCheckerConfig, data: dict) -> tuple:
    """The model's inputs (:func:`stream_input_names`) from streams ``data``."""
    return tuple(data[k] for k in stream_input_names(config))
