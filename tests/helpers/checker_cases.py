"""Shared cases for the checker's tests: one deterministic TwoRooms rollout (collected by
``checker.collect_episodes`` and replayed step by step in Python), a synthetic toy set, and a
tiny model configuration of each kind; HazardRooms streams for the memory checker and
hand-made ones. ``tests/checker/conftest.py`` serves them as session fixtures, so a test
process compiles the rollouts and trains the toy checker once."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import checker
import jaxgrid
from checker import CheckerConfig, CheckerDataset, NoisyOracleParams, noisy_oracle_policy
from checker.data import collect_streams
from checker.memory_model import MemoryCheckerConfig
from checker.train import CheckerTrainConfig, train_checker
from helpers.xla import CHEAP
from jaxgrid import sentences
from jaxgrid.constants import BLUE, DOOR, RED
from jaxgrid.wrappers import AutoReset

# One compiled rollout chunk serves every collection: same env, policy, envs and steps.
ENVS, STEPS = 4, 64
SEEK = NoisyOracleParams(epsilon=0.0, ignore_prob=0.0, seek_prob=1.0)  # deterministic
TINY = CheckerConfig(
    window=3, word_dim=8, gru_dim=16, state_dim=16, cell_dim=8, conv_channels=8,
    temporal_channels=16, mlp_dim=32,
)  # fmt: skip
MEMORY_SMALL = MemoryCheckerConfig(
    word_dim=8, gru_dim=8, cell_dim=4, conv_channels=4, state_dim=8, memory_dim=16, mlp_dim=16
)


def collect_episodes(env) -> dict[int, CheckerDataset]:
    """Full-episode datasets for lookahead 0, 1 and 2 of one deterministic rollout."""
    key = jax.random.PRNGKey(3)
    return {
        k: checker.collect_episodes(env, noisy_oracle_policy, SEEK, key, STEPS, 4, k, ENVS)
        for k in (0, 1, 2)
    }


def replay_episodes(env) -> dict[str, np.ndarray]:
    """The same rollout as :func:`collect_episodes`, replayed step by step in Python.

    ``collect`` resets ``vmap(AutoReset(env).reset)`` over ``split(split(key)[0], ENVS)``;
    the seek-mode oracle with ``epsilon = 0`` is deterministic, so the policy's key is moot.
    """
    auto = AutoReset(env)
    k_reset, _ = jax.random.split(jax.random.PRNGKey(3))
    reset = jax.jit(jax.vmap(auto.reset), compiler_options=CHEAP)
    states, ts = reset(jax.random.split(k_reset, ENVS))
    step = jax.jit(jax.vmap(auto.step), compiler_options=CHEAP)
    policy = jax.jit(
        lambda s, o: noisy_oracle_policy(SEEK, o, s, jax.random.PRNGKey(0)), compiler_options=CHEAP
    )
    images, starts, viols, monitor = [ts.observation["image"]], [np.ones(ENVS, bool)], [], []
    viols.append(np.zeros(ENVS, bool))
    monitor.append(np.zeros(ENVS, bool))
    for _ in range(STEPS):
        prev = states
        states, ts = step(states, policy(states, ts.observation))
        done = np.asarray(ts.terminated | ts.truncated)
        images.append(ts.observation["image"])
        starts.append(done)
        viols.append(np.asarray(ts.info["violation"]))
        # Independent monitor: the agent moved onto a door of the forbidden colour (TwoRooms
        # has no lava). Only checkable where the episode did not end (state not reset).
        pos = np.asarray(states.agent_pos)
        grid = np.asarray(states.grid)
        cell = grid[np.arange(ENVS), pos[:, 0], pos[:, 1]]
        moved = np.any(pos != np.asarray(prev.agent_pos), axis=1)
        colour = np.asarray(prev.extras.constraint.door_colour)
        monitor.append(moved & (cell[:, 0] == DOOR) & (cell[:, 1] == colour) & ~done)
    return {
        "image": np.stack([np.asarray(i) for i in images]),  # (T+1, E, V, V, 3)
        "start": np.stack(starts),
        "violation": np.stack(viols),
        "monitor": np.stack(monitor),
    }


def expected_labels(start, violation, k):
    """Labels by explicit loops over each env's episodes (the definition, written plainly)."""
    t_total, num_envs = start.shape
    out = {}
    for e in range(num_envs):
        for i in range(t_total - k):
            if k == 0:
                out[i, e] = bool(violation[i, e] and not start[i, e])
                continue
            label = False
            for j in range(1, k + 1):
                if any(start[i + m, e] for m in range(1, j)):
                    break  # step i + j belongs to a later episode
                label |= bool(violation[i + j, e])
            out[i, e] = label
    return out


def toy_split() -> tuple[CheckerDataset, CheckerDataset]:
    """A synthetic set, split 3:1: label 1 iff the newest frame's front cell is a door of the
    colour the sentence names (red or blue doors; sentences name red or blue)."""
    rng = np.random.default_rng(0)
    n = 1536
    windows = np.zeros((n, TINY.window, 5, 5, 3), np.uint8)
    windows[..., 0] = 1  # empty cells
    door_colour = rng.choice([RED, BLUE], n)
    has_door = rng.random(n) < 0.75
    windows[has_door, -1, 2, 3] = np.stack(
        [np.full(has_door.sum(), DOOR), door_colour[has_door], np.zeros(has_door.sum())], -1
    )
    said = rng.choice(["red", "blue"], n)
    template = rng.integers(0, 7, n)
    tokens = np.stack(
        [
            sentences.PAPER.tokenize(sentences.render(int(t), c))
            for t, c in zip(template, said, strict=True)
        ]
    )
    labels = has_door & (door_colour == np.where(said == "red", RED, BLUE))
    ds = CheckerDataset(
        windows=windows, tokens=tokens, labels=labels.astype(np.uint8),
        template_id=template.astype(np.int32), constraint_type=np.ones(n, np.int32),
        scenario=np.full(n, "toy"), meta={"lookahead": 1, "env_id": "toy", "window": 3},
    )  # fmt: skip
    return ds.split((0.75, 0.25), seed=0)


def train_toy(train: CheckerDataset):
    """``(TrainedChecker, history)`` of the tiny model on the toy training split."""
    settings = CheckerTrainConfig(
        window=TINY.window, lookahead=1, seed=0, lr=3e-3, batch_size=64, epochs=25,
        patience=25, test_fraction=0.0, blocked=0, lava_counterfactuals=False,
        final_windows=False,
    )  # fmt: skip
    trained, history, _ = train_checker(train, settings, model=TINY, progress=False)
    return trained, history


def hazard_streams() -> dict:
    """16 streams of 60 frames of HazardRooms under the random behaviour policy."""
    return collect_streams(jaxgrid.make("HazardRooms-v0"), jax.random.PRNGKey(0), 16, 60)


def random_frames(key, b, t):
    """uint8 ``(b, t, 7, 7, 3)`` frames of random cells."""
    k1, k2, k3 = jax.random.split(key, 3)
    obj = jax.random.randint(k1, (b, t, 7, 7), 0, 11)
    col = jax.random.randint(k2, (b, t, 7, 7), 0, 6)
    st = jax.random.randint(k3, (b, t, 7, 7), 0, 3)
    return jnp.stack([obj, col, st], -1).astype(jnp.uint8)


def budget_streams(n, t):
    """``n`` hand-made budget streams of ``t`` frames, each one episode with nothing in it."""
    d = {
        "starts": np.zeros((n, t), bool),
        "cost": np.zeros((n, t)),
        "violation": np.zeros((n, t), np.int32),
        "label": np.zeros((n, t), np.int32),
        "valid": np.ones((n, t), bool),
        "ctype": np.full((n, t), 1),  # budget
        "next_cost": np.zeros((n, t)),
    }
    d["starts"][:, 0] = True
    return d


def fake_streams(n, t):
    """Streams shaped as :func:`checker.data.collect_streams`'s, random frames and labels."""
    rng = np.random.default_rng(0)
    starts = np.zeros((n, t), bool)
    starts[:, 0] = True
    return {
        "frames": np.asarray(random_frames(jax.random.PRNGKey(6), n, t)),
        "tokens": np.zeros((n, t, MEMORY_SMALL.max_len), np.int32),
        "starts": starts,
        "label": (rng.random((n, t)) < 0.2).astype(np.int32),
        "cost": np.zeros((n, t)),
        "violation": np.zeros((n, t), np.int32),
        "ctype": np.ones((n, t), np.int32),
        "template": np.zeros((n, t), np.int32),
        "valid": np.ones((n, t), bool),
        "next_cost": np.zeros((n, t)),
    }
