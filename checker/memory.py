"""A checker with memory: a GRU over the episode's frames, for constraints that count.

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
checker of the step into each frame (``label="into"``) needs it most. A learner knows the
action it took, and a shield the action of each candidate.

Usage: ``python -m checker.memory --json runs/memory_checker.json [--out DIR]`` (``--help``).

Data are whole streams of ``BatchedAutoReset(HazardRooms)`` under a random behaviour policy
(:func:`collect_streams`), collected on device; training is truncated-free backpropagation
through each stream (:func:`train_memory_checker`). :func:`evaluate_streams` reports AUROC
overall, per constraint type, and on the budget episodes whose violation comes more than
``late`` steps after the first costly event, which no window of ``late`` frames can count.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import flax.linen as nn
import flax.struct as struct
import jax
import jax.numpy as jnp
import numpy as np
import optax

from checker.metrics import auroc
from checker.model import NUM_COLOURS, NUM_OBJECTS, NUM_STATES, embed_cells, encode_sentence
from checker.trained import (
    check_vocab,
    check_writable_file,
    fresh_checker_dir,
    read_meta,
    read_params,
    write_params,
)
from jaxgrid import hazard_language as HL
from jaxgrid.oracle import oracle_action
from jaxgrid.wrappers import BatchedAutoReset

# Behaviour policy over MiniGrid's actions (left, right, forward, pickup, drop, toggle, done):
# mostly forward, doors opened and the key picked up now and then, never drop or done.
BEHAVIOUR = (0.15, 0.15, 0.55, 0.075, 0.0, 0.075, 0.0)

# What a frame's label says (:func:`relabel`): "next", the step out of the frame violates (the
# paper's just-before label); "into", the step into the frame violated.
LABELS = ("next", "into")


_FLAGS = ("memory", "actions")  # MemoryCheckerConfig's bool fields
#: The "action" into an episode's first frame (one past MiniGrid's seven actions).
NO_ACTION = 7


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

    It offers the learner's stream interface of the window checker
    (:class:`checker.trained.TrainedChecker`): ``embed_states``, ``encode_language``,
    ``stream_start`` and ``stream_step``, whose memory is the GRU state ``(E, memory_dim)``
    instead of the last frames, so PPO carries it per env and its shield scores candidates
    with it. Pure and jittable.
    """

    params: Any
    config: MemoryCheckerConfig = struct.field(pytree_node=False)
    env_id: str = struct.field(pytree_node=False, default="")
    threshold: float = struct.field(pytree_node=False, default=0.5)
    label: str = struct.field(pytree_node=False, default="next")  # one of LABELS
    kind = "memory"

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


def new_memory_checker(config: MemoryCheckerConfig, key: jax.Array, **meta):
    """An untrained :class:`TrainedMemoryChecker` (``meta``: ``env_id``, ``threshold``)."""
    return TrainedMemoryChecker(params=_init(config, key), config=config, **meta)


def _init(config: MemoryCheckerConfig, key: jax.Array):
    v, lead = config.view_size, (1, 1)
    frames = jnp.zeros(lead + (v, v, 3), jnp.uint8)
    tokens = jnp.zeros(lead + (config.max_len,), jnp.int32)
    actions = jnp.full(lead, NO_ACTION, jnp.int32) if config.actions else None
    return jax.jit(MemoryChecker(config).init)(key, frames, jnp.ones(lead, bool), tokens, actions)


def save(trained: TrainedMemoryChecker, directory) -> str:
    """Write the checker to ``directory``; :func:`checker.load` reads it back."""
    meta = {
        "kind": "memory",
        "config": dataclasses.asdict(trained.config),
        "env_id": trained.env_id,
        "threshold": trained.threshold,
        "label": trained.label,
        "vocab": list(HL.VOCAB),
        "max_len": HL.MAX_LEN,
    }
    return write_params(trained.params, directory, meta)


def load(directory, meta: dict | None = None) -> TrainedMemoryChecker:
    """The memory checker saved in ``directory`` (errors as :func:`checker.load`'s)."""
    meta = read_meta(directory) if meta is None else meta
    check_vocab(meta, f"checker {directory}", HL)
    config = MemoryCheckerConfig(**meta["config"])
    template = jax.eval_shape(lambda: _init(config, jax.random.PRNGKey(0)))
    params = read_params(directory, template, meta)
    return TrainedMemoryChecker(
        params=params, config=config, env_id=str(meta["env_id"]),
        threshold=float(meta["threshold"]), label=str(meta.get("label", "next")),
    )  # fmt: skip


# ------------------------------------------------------------------------------------ data


def collect_streams(
    env, key: jax.Array, num_envs: int, num_steps: int, guided: float = 0.0
) -> dict:
    """``num_envs`` streams of ``num_steps`` frames of ``BatchedAutoReset(env)`` (fresh
    layouts drawn only where an episode ended) under :data:`BEHAVIOUR`, from fresh resets.

    ``guided`` > 0 takes each step's action, with that probability, from the BFS oracle
    (:func:`jaxgrid.oracle.oracle_action`) instead: half of the streams follow the oracle
    that obeys the constraint, half the one that plans through lava and forbidden doors. A
    random policy seldom leaves its first room; guided streams pass doors, carry the key and
    reach the goal, where trained agents go, and violate there too. 0 (the default) draws
    every action from :data:`BEHAVIOUR`, as before the option existed.

    Returns numpy arrays, ``(N, T, ...)``:

    ``frames`` (uint8 images), ``tokens``, ``starts`` (the frame is an episode's first),
    ``action`` (the action that led into the frame; :data:`NO_ACTION` at a start),
    ``label`` (the next step violates: ``info["violation"]`` of the step taken from this
    frame, which belongs to this frame's episode even when that step ends it), ``next_cost``
    (that step's ``info["cost"]``), ``cost`` and
    ``violation`` (of the step that produced the frame; 0 at a start), ``ctype`` and
    ``template`` (``info``'s ``constraint_type`` and ``template_id``) and ``valid`` (True
    everywhere: the scan runs the step out of every frame, the last one included, so every
    frame has its label; the training loss and the metrics take it as a mask).
    """
    if not 0.0 <= guided <= 1.0:
        raise ValueError(f"guided must be a probability in [0, 1], got {guided!r}")
    wrapped = BatchedAutoReset(env)
    k_reset, k_run = jax.random.split(key)
    probs = jnp.asarray(BEHAVIOUR)

    @jax.jit
    def run(k_reset, k_run):
        states, ts = wrapped.reset(jax.random.split(k_reset, num_envs))

        def body(carry, k):
            states, ts, start, last = carry
            actions = jax.random.choice(k, len(BEHAVIOUR), (num_envs,), p=probs)
            if guided > 0:  # static: without guidance the streams are drawn as before
                obey = jnp.arange(num_envs) % 2 == 0  # alternate streams obey the constraint
                expert = jax.vmap(
                    lambda s, o: oracle_action(s, obey_constraint=o, avoid_lava=o)
                )(states, obey)
                follow = jax.random.bernoulli(jax.random.fold_in(k, 1), guided, (num_envs,))
                actions = jnp.where(follow, expert, actions)
            new_states, new_ts = wrapped.step(states, actions)
            frame = {
                "frames": ts.observation["image"],
                "tokens": ts.observation["constraint"],
                "starts": start,
                "action": jnp.where(start, NO_ACTION, last),
                "cost": jnp.where(start, 0.0, ts.info["cost"]),
                "violation": jnp.where(start, 0, ts.info["violation"]).astype(jnp.int32),
                "ctype": ts.info["constraint_type"],
                "template": ts.info["template_id"],
                "label": new_ts.info["violation"].astype(jnp.int32),
                "next_cost": new_ts.info["cost"],
            }
            ended = new_ts.terminated | new_ts.truncated
            return (new_states, new_ts, ended, actions), frame

        first = (states, ts, jnp.ones(num_envs, bool), jnp.full(num_envs, NO_ACTION, jnp.int32))
        _, frames = jax.lax.scan(body, first, jax.random.split(k_run, num_steps))
        return jax.tree.map(lambda a: jnp.swapaxes(a, 0, 1), frames)

    out = {k: np.asarray(v) for k, v in run(k_reset, k_run).items()}
    out["valid"] = np.ones(out["starts"].shape, bool)  # every frame has its next step here
    return out


def relabel(data: dict, label: str) -> dict:
    """``data`` (:func:`collect_streams`) with ``label`` saying what a checker of that kind
    learns: "next" (unchanged), whether the step out of the frame violates, the paper's
    just-before label, which a learner turns into a penalty before the violation; "into",
    whether the step into the frame violated (``violation``). A memory checker can tell the
    latter from the frame and its memory alone, while the former also depends on the action
    not yet taken; a shield, which scores the frame each candidate action leads to, asks the
    latter. The episodes' final frames are not in the streams (the auto-reset replaces them),
    so an "into" checker never sees a violation on an episode's last step."""
    if label not in LABELS:
        raise ValueError(f"label must be one of {LABELS}, got {label!r}")
    if label == "next":
        return data
    return {**data, "label": data["violation"].astype(np.int32)}


# ------------------------------------------------------------------------------- training


@dataclasses.dataclass(frozen=True)
class MemoryTrainConfig:
    """Data and optimisation settings of a memory checker (:func:`train_memory_checker`;
    ``streams`` and ``steps`` size what :func:`collect_streams` gathers for it); the defaults
    are the memory checker of the HazardRooms experiment."""

    streams: int = 512  # streams collected, for training and again for the test
    steps: int = 160  # frames per stream
    updates: int = 600  # training updates
    batch_streams: int = 16  # streams per update
    lr: float = 1e-3  # Adam step size
    positive_weight: float = 10.0  # violations are rare: weight their loss
    guided: float = 0.0  # share of the actions from the BFS oracle (half the streams obey it)
    # "next": the step out of each frame violates (the paper's just-before label); "into":
    # the step into it did (what a shield asks of a candidate frame)
    label: str = "next"
    seed: int = 0  # seeds the streams (the test streams: seed + 1000) and the training

    def __post_init__(self):
        me = type(self).__name__
        for name in ("streams", "steps", "updates", "batch_streams"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{me}.{name} must be an int >= 1, got {value!r}")
        for name in ("lr", "positive_weight"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{me}.{name} must be > 0, got {getattr(self, name)!r}")
        if not 0.0 <= self.guided <= 1.0:
            raise ValueError(f"{me}.guided must be in [0, 1], got {self.guided!r}")
        if self.label not in LABELS:
            raise ValueError(f"{me}.label must be one of {LABELS}, got {self.label!r}")
        if self.batch_streams > self.streams:
            raise ValueError(
                f"{me}.batch_streams ({self.batch_streams}) exceeds {me}.streams ({self.streams})"
            )


def _loss(model, params, batch, positive_weight):
    logits = model.apply(params, *_inputs(model.config, batch))
    y = batch["label"].astype(jnp.float32)
    weight = jnp.where(y > 0, positive_weight, 1.0) * batch["valid"]
    losses = optax.sigmoid_binary_cross_entropy(logits, y)
    return jnp.sum(losses * weight) / jnp.maximum(jnp.sum(weight), 1.0)


def train_memory_checker(
    data: dict, config: MemoryCheckerConfig, train: MemoryTrainConfig, progress=None
):
    """Fit :class:`MemoryChecker` on ``data`` (:func:`collect_streams`); returns
    ``(params, losses)``. Each update takes ``batch_streams`` whole streams."""
    model = MemoryChecker(config)
    key = jax.random.PRNGKey(train.seed)
    n = data["starts"].shape[0]
    if train.batch_streams > n:
        raise ValueError(f"batch_streams {train.batch_streams} exceeds the {n} streams collected")
    fields = _inputs_named(config) + ("label", "valid")
    arrays = {k: jnp.asarray(data[k]) for k in fields}
    sample = jax.tree.map(lambda a: a[:1], arrays)
    params = jax.jit(model.init)(key, *_inputs(config, sample))
    tx = optax.adam(train.lr)
    opt = tx.init(params)

    @jax.jit
    def update(params, opt, key):
        idx = jax.random.choice(key, n, (train.batch_streams,), replace=False)
        batch = jax.tree.map(lambda a: a[idx], arrays)
        loss, grads = jax.value_and_grad(lambda p: _loss(model, p, batch, train.positive_weight))(
            params
        )
        updates, opt = tx.update(grads, opt, params)
        return optax.apply_updates(params, updates), opt, loss

    losses = []
    for i, k in enumerate(jax.random.split(jax.random.fold_in(key, 1), train.updates)):
        params, opt, loss = update(params, opt, k)
        losses.append(float(loss))
        if progress is not None:
            progress(i, losses[-1])
    return params, np.asarray(losses)


def fit(data: dict, config: MemoryCheckerConfig, train: MemoryTrainConfig, desc=None):
    """:func:`train_memory_checker` with a progress bar named ``desc`` (None: no bar)."""
    if desc is None:
        return train_memory_checker(data, config, train)
    from tqdm.auto import tqdm

    with tqdm(total=train.updates, desc=desc, unit="update", leave=False) as bar:
        return train_memory_checker(data, config, train, lambda i, loss: bar.update(1))


def predict_streams(params, config: MemoryCheckerConfig, data: dict, batch: int = 64):
    """Violation probabilities ``(N, T)`` of every frame of ``data``."""
    model = MemoryChecker(config)
    apply = jax.jit(lambda p, *x: jax.nn.sigmoid(model.apply(p, *x)))
    out = []
    for i in range(0, data["starts"].shape[0], batch):
        part = (data[k][i : i + batch] for k in _inputs_named(config))
        out.append(np.asarray(apply(params, *part)))
    return np.concatenate(out)


_INPUTS = ("frames", "starts", "tokens", "action")


def _inputs_named(config: MemoryCheckerConfig) -> tuple[str, ...]:
    """The names of the model's inputs: frames, starts, tokens (and the actions it reads)."""
    return _INPUTS if config.actions else _INPUTS[:3]


def _inputs(config: MemoryCheckerConfig, data: dict) -> tuple:
    """The model's inputs (:func:`_inputs_named`) from streams ``data``."""
    return tuple(data[k] for k in _inputs_named(config))


def late_violation_mask(data: dict, late: int, label: str = "next") -> np.ndarray:
    """bool ``(N, T)``: frames of the episodes whose first violation comes more than ``late``
    steps after their first costly event (a budget counted beyond a window of ``late``
    frames). Streams begin with a reset, so every episode is seen from its start. ``label``
    says what ``data["label"]`` marks (:func:`relabel`)."""
    shift = 1 if label == "next" else 0
    starts, cost, labels = data["starts"], data["cost"] > 0, data["label"] > 0
    mask = np.zeros(starts.shape, bool)
    for e in range(starts.shape[0]):
        begins = [*np.flatnonzero(starts[e]), starts.shape[1]]
        for a, b in zip(begins[:-1], begins[1:], strict=False):
            # frame t's cost is the step into it; a "next" label is the step out of it
            # (t + 1): such labels, unlike ``violation``, keep an episode's final step
            first_cost = np.flatnonzero(cost[e, a:b])
            first_violation = np.flatnonzero(labels[e, a:b]) + shift
            if len(first_cost) and len(first_violation):
                mask[e, a:b] = first_violation[0] - first_cost[0] > late
    return mask


def evaluate_streams(probs, data: dict, late: int = 10, label: str = "next") -> dict:
    """AUROC of ``probs`` against the labels: overall, per constraint type, on late budget
    violations (:func:`late_violation_mask`) and on the budget frames whose labelled step
    costs (``costly_budget``: is this entry one too many?), with the positive counts behind
    each. ``label`` says what ``data["label"]`` marks (:func:`relabel`)."""
    y, valid = data["label"] > 0, data["valid"]
    report = {"auroc": auroc(y[valid], probs[valid]), "positives": int(y[valid].sum())}
    per_type = {}
    for i, name in enumerate(HL.CONSTRAINT_TYPES):
        m = valid & (data["ctype"] == i)
        per_type[name] = {"auroc": auroc(y[m], probs[m]), "positives": int(y[m].sum())}
    report["per_type"] = per_type
    budget = data["ctype"] == HL.CONSTRAINT_TYPES.index("budget")
    m = valid & budget & late_violation_mask(data, late, label)
    report["late_budget"] = {"late": late, "auroc": auroc(y[m], probs[m]),
                             "positives": int(y[m].sum())}  # fmt: skip
    # Counting itself: among budget frames whose labelled step costs, which ones exceed the
    # budget? A checker that does not count cannot rank these (AUROC near 0.5).
    step_cost = data["next_cost"] if label == "next" else data["cost"]
    m = valid & budget & (step_cost > 0)
    report["costly_budget"] = {"auroc": auroc(y[m], probs[m]), "positives": int(y[m].sum())}
    return report


def run(
    env_id: str = "HazardRooms-v0",
    num_envs: int | None = None,
    num_steps: int | None = None,
    config: MemoryCheckerConfig | None = None,
    train: MemoryTrainConfig | None = None,
    splits: Sequence[str] = ("train", "heldout"),
    late: int = 10,
    progress: bool = False,
    out: str | None = None,
) -> dict:
    """Collect streams on the train split, train, and evaluate on fresh streams of each of
    ``splits`` (other seeds). The report holds the settings (``checker_config``,
    ``train_config``), one :func:`evaluate_streams` entry per split and the wall seconds.
    ``num_envs`` and ``num_steps`` (None: ``train.streams`` and ``train.steps``) size each
    split's streams; with ``out`` the trained checker is saved there (:func:`save`)."""
    import jaxgrid

    config = config or MemoryCheckerConfig()
    train = train or MemoryTrainConfig()
    num_envs = train.streams if num_envs is None else num_envs
    num_steps = train.steps if num_steps is None else num_steps
    t0 = time.perf_counter()
    data = collect_streams(
        jaxgrid.make(env_id), jax.random.PRNGKey(train.seed), num_envs, num_steps, train.guided
    )
    data = relabel(data, train.label)
    params, losses = fit(data, config, train, "train memory checker" if progress else None)
    if out is not None:
        save(TrainedMemoryChecker(params=params, config=config, env_id=env_id,
                                  label=train.label), out)  # fmt: skip
    report = {
        "env_id": env_id,
        "num_envs": num_envs,
        "num_steps": num_steps,
        "checker_config": dataclasses.asdict(config),
        "train_config": dataclasses.asdict(train),
        "train_positives": int(data["label"].sum()),
        "final_loss": float(losses[-50:].mean()),
    }
    for split in splits:
        env = jaxgrid.make(env_id, split=split)
        test = collect_streams(
            env, jax.random.PRNGKey(train.seed + 1000), num_envs, num_steps, train.guided
        )
        test = relabel(test, train.label)
        report[split] = evaluate_streams(
            predict_streams(params, config, test), test, late, train.label
        )
    report["wall_s"] = time.perf_counter() - t0
    return report


PROG = "python -m checker.memory"


@dataclasses.dataclass(frozen=True)
class MemoryRun:
    """Train the recurrent checker on HazardRooms streams; AUROC per type."""

    train: MemoryTrainConfig = MemoryTrainConfig()  # streams (--envs) and training
    late: int = 10  # steps that make a violation late
    memory: bool = True  # False (--no-memory): zero the memory at every frame (the ablation)
    actions: bool = False  # read the action into each frame beside it
    json: str | None = None  # write the report here
    out: str | None = None  # save the checker here: new, empty, or (--overwrite) a checker's
    overwrite: bool = False  # clear an earlier checker's files from --out first (else refused)

    def __post_init__(self):
        if self.late < 1:
            raise ValueError(f"MemoryRun.late must be at least 1, got {self.late}")
        if self.json is not None:
            check_writable_file(self.json, "MemoryRun.json")
        if self.out is not None and (not self.out or Path(self.out).is_file()):
            raise ValueError(f"MemoryRun.out {self.out!r} is not a directory")


def main(argv=None) -> dict:
    """``python -m checker.memory``: train and measure a memory checker on HazardRooms.

    Before any work, bad flags and an unwritable ``--json`` exit with status 2, and so do an
    ``--out`` held by another process (locked for the run, :func:`jaxgrid.rundir.lock`) and
    a non-empty one, unless it holds an earlier checker and ``--overwrite`` is given
    (:func:`checker.trained.fresh_checker_dir`, as for ``python -m checker``)."""
    import contextlib
    import json

    from checker import cli
    from jaxgrid.io import write_json
    from jaxgrid.rundir import lock

    args = cli.parse(MemoryRun, argv, prog=PROG, description=MemoryRun.__doc__,
                     names={MemoryTrainConfig: {"streams": "envs"}})  # fmt: skip
    with lock(args.out, PROG) if args.out else contextlib.nullcontext():
        if args.out:
            fresh_checker_dir(args.out, args.overwrite)
        t = args.train
        print(f"{PROG}: {t.streams} streams x {t.steps} frames of HazardRooms-v0, {t.updates} "
              "updates", file=sys.stderr, flush=True)  # fmt: skip
        report = run(config=MemoryCheckerConfig(memory=args.memory, actions=args.actions),
                     train=t, late=args.late, progress=True, out=args.out)  # fmt: skip
    print(json.dumps({k: report[k] for k in ("train", "heldout") if k in report}, indent=1))
    if args.json:
        write_json(args.json, report)
    return report


if __name__ == "__main__":
    from checker import cli

    cli.run_main(main, PROG)
