"""PPO with the memory checker (checker.memory): its GRU state carried per env in the rollout."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.agents_cases import CHECKER_CONFIG, TINY, fast_jit
from helpers.xla import batch_reset, batch_step

import jaxgrid
from agents.shield import make_shield
from agents.train import make_learner
from checker import memory_model as MM
from checker.model import new_checker
from checker.protocol import MOVES, NO_ACTION
from jaxgrid.wrappers import BatchedAutoReset

SENTENCES = (
    "avoid lava",
    "do not step on water more than twice",
    "after you pick up the key, do not use the red door",
)
HAZARD = dataclasses.replace(
    TINY, env_id="HazardRooms-v0", num_steps=24, total_timesteps=8 * 24 * 2, gamma=0.0,
    penalty=1.0, soft_checker=True,
    env_kwargs=(("sentences", SENTENCES), ("max_steps", 7)),
)  # fmt: skip
SMALL = MM.MemoryCheckerConfig(
    word_dim=8, gru_dim=8, cell_dim=4, conv_channels=4, state_dim=8, memory_dim=16, mlp_dim=16
)


@pytest.fixture(scope="module")
def memory_checker():
    return MM.new_memory_checker(SMALL, jax.random.PRNGKey(5), env_id="HazardRooms-v0")


def _streams(observed, finals, done):
    """Per env, the frames the memory checker reads in order (an episode's first observation,
    then the final observation of each of its steps) as indices into ``observed`` (0) or
    ``finals`` (1), with episode starts and the rollout step each frame is scored at (-1: an
    episode's first frame, not scored)."""
    steps, envs = done.shape
    out = []
    for e in range(envs):
        rows = [(0, 0, True, -1)]
        for t in range(steps):
            rows.append((1, t, False, t))
            if done[t, e] and t + 1 < steps:
                rows.append((0, t + 1, True, -1))
        out.append(rows)
    return out


@pytest.mark.parametrize("actions", [pytest.param(False, marks=pytest.mark.slow), True])
def test_the_rollout_scores_each_step_as_the_whole_stream_would(memory_checker, actions):
    """The probability the rollout penalises (soft checker, gamma 0: reward = env reward -
    probability) equals the memory checker run over each env's whole stream of frames: the
    GRU state carried per env, reset where an episode starts, is the stream's memory. A
    checker of ``actions`` reads each frame with the action taken into it."""
    if actions:
        config = dataclasses.replace(SMALL, actions=True)
        memory_checker = MM.new_memory_checker(config, jax.random.PRNGKey(5))
    cfg = dataclasses.replace(HAZARD, reward_mode="checker")
    learner = make_learner(cfg, memory_checker)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(2))
    _, traj, _ = fast_jit(lambda r: learner.rollout(r, r.key))(runner)
    # Replay the env with the same actions to get every frame and env reward.
    step = jax.jit(BatchedAutoReset(learner.env).step)
    state = runner.env.state
    observed, finals, rewards = [runner.env.obs["image"]], [], []
    for a in np.asarray(traj.action):
        state, ts = step(state, jnp.asarray(a))
        observed.append(ts.observation["image"])
        finals.append(ts.info["final_observation"]["image"])
        rewards.append(ts.reward)
    images = (np.asarray(observed), np.asarray(finals))
    done = np.asarray(traj.done)
    assert done.sum() >= 8  # episodes of 7 steps: several resets inside the rollout
    prob = np.asarray(rewards) - np.asarray(traj.reward)
    # Each env's stream, padded to one length, read by the checker in one call.
    streams = _streams(*images, done)
    length = max(len(s) for s in streams)
    frames = np.zeros((len(streams), length) + images[0].shape[2:], np.uint8)
    starts = np.ones((len(streams), length), bool)
    tokens = np.zeros((len(streams), length, learner.table.shape[1]), np.int32)
    moves = np.full((len(streams), length), NO_ACTION, np.int32)
    sentence, table = np.asarray(traj.sentence), np.asarray(learner.table)
    for e, rows in enumerate(streams):
        for i, (which, t, start, scored) in enumerate(rows):
            frames[e, i], starts[e, i] = images[which][t, e], start
            tokens[e, i] = table[sentence[t, e]]
            if scored >= 0:  # the final observation of step t, reached by its action
                moves[e, i] = traj.action[t, e]
    logits = jax.jit(memory_checker.logits)(frames, starts, tokens, moves)
    out = np.asarray(jax.nn.sigmoid(logits))
    expected = np.full(done.shape, np.nan)
    for e, rows in enumerate(streams):
        for i, (_, _, _, scored) in enumerate(rows):
            if scored >= 0:
                expected[scored, e] = out[e, i]
    np.testing.assert_allclose(prob, expected, atol=2e-5)
    assert np.ptp(prob) > 1e-3


@pytest.mark.slow  # 25-50 s of compiles; the stream interface it uses is the window shield's
def test_the_shield_trains_and_evaluates_with_the_memory_checker(memory_checker):
    """Shield mode with a recurrent policy: candidates are scored from the carried GRU state
    in training, and from the shield's own memory of each episode in evaluation."""
    cfg = dataclasses.replace(HAZARD, reward_mode="shield", soft_checker=False, recurrent=True,
                              num_steps=8, gamma=0.99)  # fmt: skip
    learner = make_learner(cfg, memory_checker)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))
    assert runner.env.frames.shape == (cfg.num_envs, SMALL.memory_dim)
    runner, metrics = fast_jit(learner.update)(runner)
    assert all(np.isfinite(np.asarray(v)).all() for v in jax.tree.leaves(metrics))
    assert not np.allclose(np.asarray(runner.env.frames), 0.0)
    evaluate = fast_jit(learner.evaluate, static_argnums=2)
    episodes = evaluate(runner.params, jax.random.PRNGKey(1), 4)
    assert (np.asarray(episodes["length"]) > 0).all()


def test_a_checker_of_the_step_into_each_frame_judges_moves_only(memory_checker):
    """A memory checker of the step into each frame (``lookahead`` 0) judges the step itself,
    which only a move can make a violation: its shield scores forward as the all-action shield
    does and never blocks another action; one of just-before labels (turning may face a
    hazard) judges them all."""
    env = jaxgrid.make("HazardRooms-v0", sentences=SENTENCES)
    into = memory_checker.replace(lookahead=0)
    assert make_shield(env, "checker", memory_checker).judged is None
    shield = make_shield(env, "checker", into)
    assert shield.judged == MOVES
    states, ts = batch_reset(env, jax.random.split(jax.random.PRNGKey(2), 16))
    lang = fast_jit(into.encode_language)(ts.observation["constraint"])
    memory = fast_jit(lambda image: into.stream_start(into.embed_states(image), lang))(
        ts.observation["image"]
    )
    moves = np.asarray(fast_jit(shield.risk)(states, memory, lang))
    every = np.asarray(fast_jit(shield.replace(judged=None).risk)(states, memory, lang))
    others = [a for a in range(env.num_actions) if a not in MOVES]
    np.testing.assert_allclose(moves[:, MOVES], every[:, MOVES], atol=1e-6)
    assert (moves[:, others] == 0).all() and (every[:, others] > 0).all()


def test_a_window_checker_of_the_paper_language_is_refused_on_hazard_rooms():
    window = new_checker(dataclasses.replace(CHECKER_CONFIG, view_size=7), jax.random.PRNGKey(0))
    cfg = dataclasses.replace(HAZARD, reward_mode="checker")
    with pytest.raises(ValueError, match="vocabulary of .* token ids"):
        make_learner(cfg, window)


def test_a_shield_of_actions_reads_each_candidate_with_its_action():
    """A checker of ``actions`` scores a candidate frame with the action that reaches it:
    forward for a step-into shield, and each action for an all-action one."""
    env = jaxgrid.make("HazardRooms-v0", sentences=SENTENCES)
    into = MM.new_memory_checker(
        dataclasses.replace(SMALL, actions=True), jax.random.PRNGKey(6), lookahead=0
    )
    shield = make_shield(env, "checker", into)
    states, ts = batch_reset(env, jax.random.split(jax.random.PRNGKey(2), 16))
    lang = fast_jit(into.encode_language)(ts.observation["constraint"])
    memory = fast_jit(shield.start)(ts.observation)[0]
    risk = np.asarray(fast_jit(shield.risk)(states, memory, lang))
    _, moved = batch_step(env, states, jnp.full(16, MOVES[0], jnp.int32))

    @fast_jit
    def score(action):
        emb = into.embed_states(moved.observation["image"], jnp.full(16, action, jnp.int32))
        return jax.nn.sigmoid(into.candidate_logits(memory, emb[:, None], lang))[:, 0]

    np.testing.assert_allclose(risk[:, MOVES[0]], score(MOVES[0]), atol=1e-6)
    assert np.abs(risk[:, MOVES[0]] - score(NO_ACTION)).min() > 0
