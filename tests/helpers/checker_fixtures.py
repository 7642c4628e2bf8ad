"""The tiny training runs behind ``tests/fixtures/checkers/``: one per checker kind, from fixed
seeds, and the inputs their saved checkers are asked about.

``tests/fixtures/checkers/{window,memory}/`` hold the checkers these runs saved, with
``expected.json`` (each one's parameter sha256) and ``expected.npz`` (their predictions on
the inputs below). ``tests/checker/test_fixtures.py`` loads the saved checkers and checks
their predictions, and reruns both trainings and checks the sha256 of what they give: saved
checkers keep loading, and the same seeds keep giving the same parameters.

The numbers hold under the suite's XLA settings (``tests/conftest.py``); other compiler
settings may change the last bits.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import checker
import jaxgrid
from checker import memory_model as MM
from checker.data import collect_streams, relabel
from checker.metrics import predict_streams
from checker.train import CheckerTrainConfig, MemoryTrainConfig, train_checker, train_memory_checker

FIXTURES = Path(__file__).resolve().parents[1] / "fixtures" / "checkers"

WINDOW_MODEL = checker.CheckerConfig(
    window=3, word_dim=8, gru_dim=16, state_dim=16, cell_dim=8, conv_channels=8,
    temporal_channels=16, mlp_dim=32,
)  # fmt: skip
WINDOW_TRAIN = CheckerTrainConfig(
    window=3, lookahead=1, seed=0, epochs=12, batch_size=32, lr=3e-3, patience=12,
    blocked=1, final_windows=True,
)  # fmt: skip
MEMORY_MODEL = MM.MemoryCheckerConfig(
    word_dim=8, gru_dim=8, cell_dim=4, conv_channels=4, state_dim=8, memory_dim=16, mlp_dim=16,
    actions=True,
)  # fmt: skip
MEMORY_TRAIN = MemoryTrainConfig(streams=16, steps=48, updates=200, batch_streams=8, lr=3e-3)


def window_data():
    """384 balanced TwoRooms windows (final windows among them) of the noisy oracle."""
    oracle = checker.NoisyOracleParams(salt=WINDOW_TRAIN.seed)
    return checker.collect(
        jaxgrid.make("TwoRooms-v0"), checker.noisy_oracle_policy, oracle, jax.random.PRNGKey(0),
        384, WINDOW_TRAIN.window, WINDOW_TRAIN.lookahead, 16, env_id="TwoRooms-v0",
        final_windows=True,
    )  # fmt: skip


def train_window():
    """The window checker of :data:`WINDOW_MODEL` trained on :func:`window_data`."""
    trained, _, _ = train_checker(window_data(), WINDOW_TRAIN, model=WINDOW_MODEL, progress=False)
    return trained


def memory_data() -> dict:
    """16 HazardRooms streams of 48 frames of the behaviour policy."""
    env = jaxgrid.make("HazardRooms-v0")
    data = collect_streams(env, jax.random.PRNGKey(MEMORY_TRAIN.seed), MEMORY_TRAIN.streams,
                              MEMORY_TRAIN.steps, MEMORY_TRAIN.guided)  # fmt: skip
    return relabel(data, MEMORY_TRAIN.lookahead)


def train_memory(data: dict | None = None):
    """The memory checker of :data:`MEMORY_MODEL` trained on :func:`memory_data`."""
    data = memory_data() if data is None else data
    params, _ = train_memory_checker(data, MEMORY_MODEL, MEMORY_TRAIN)
    return MM.TrainedMemoryChecker(params=params, config=MEMORY_MODEL, env_id="HazardRooms-v0",
                                   threshold=0.4, lookahead=MEMORY_TRAIN.lookahead)  # fmt: skip


def window_inputs(data) -> dict:
    """The first 32 windows and sentences of :func:`window_data`'s dataset."""
    return {"windows": data.windows[:32], "tokens": data.tokens[:32]}


def memory_inputs(data: dict) -> dict:
    """The first 12 frames of four of :func:`memory_data`'s streams."""
    return {k: data[k][:4, :12] for k in ("frames", "starts", "tokens", "action")}


def window_predictions(trained, inputs: dict) -> dict:
    """What a window checker says on ``inputs`` (:func:`window_inputs`): ``predict``'s
    probabilities, the PPO reward's (ring buffer) and the shield's candidate logits."""
    windows, tokens = inputs["windows"], inputs["tokens"]
    probs = checker.predict(trained, windows, tokens)
    reward = jax.jit(checker.violation_prob)(trained, jnp.asarray(windows), jnp.asarray(tokens))
    emb = jax.jit(trained.embed_states)(jnp.asarray(windows))
    lang = jax.jit(trained.encode_language)(jnp.asarray(tokens))
    past = emb[:, :-1]
    cand = (
        jnp.broadcast_to(emb[:, -1:], (emb.shape[0], 3, emb.shape[-1]))
        * jnp.arange(1, 4)[None, :, None]
    )
    shield = jax.jit(trained.candidate_logits)(past, cand, lang)
    return {"probs": probs, "reward": np.asarray(reward), "candidates": np.asarray(shield)}


def memory_predictions(trained, x: dict) -> dict:
    """What a memory checker says on ``x`` (:func:`memory_inputs`): the streams read at once,
    and read a step at a time from ``stream_start`` (what PPO carries per env)."""
    probs = predict_streams(trained.params, trained.config, x)
    emb = jax.jit(trained.embed_states)(jnp.asarray(x["frames"]), jnp.asarray(x["action"]))
    lang = jax.jit(trained.encode_language)(jnp.asarray(x["tokens"]))
    start, step = jax.jit(trained.stream_start), jax.jit(trained.stream_step)
    memory = start(emb[:, 0], lang[:, 0])
    logits = []
    for t in range(1, 7):
        logit, memory = step(memory, emb[:, t], lang[:, t])
        logits.append(np.asarray(logit))
    cand = jax.jit(trained.candidate_logits)(memory, emb[:, 7:10], lang[:, 0])
    return {"probs": probs, "steps": np.stack(logits, 1), "candidates": np.asarray(cand)}


def settings() -> dict:
    """The runs' settings, recorded beside their results."""
    return {"window": {"model": dataclasses.asdict(WINDOW_MODEL),
                       "train": dataclasses.asdict(WINDOW_TRAIN)},
            "memory": {"model": dataclasses.asdict(MEMORY_MODEL),
                       "train": dataclasses.asdict(MEMORY_TRAIN)}}  # fmt: skip
