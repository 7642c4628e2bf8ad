"""``agents.shield`` and the shield modes: candidates are the env's own steps, the checker
judge scores the raw window that ends at each candidate, blocked actions are never taken, the
monitor shield never lets a violation through, and PPO's ratio uses the mask it acted with."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.agents_cases import TINY, fast_jit

import checker.reward as creward
import jaxgrid
from agents.evaluation import play_episodes
from agents.losses import ppo_loss
from agents.shield import allow_least_risky, blocked_mass, make_shield, mask_logits
from agents.train import make_learner
from checker.protocol import MOVES


def test_masked_policy_renormalises_over_the_allowed_actions():
    logits = jnp.array([[0.0, 1.0, 2.0, 3.0]])
    allowed = jnp.array([[True, False, True, False]])
    probs = jax.nn.softmax(mask_logits(logits, allowed))
    expected = np.exp([0.0, 2.0]) / np.exp([0.0, 2.0]).sum()
    np.testing.assert_allclose(probs[0, [0, 2]], expected, rtol=1e-6)
    assert probs[0, 1] == 0 and probs[0, 3] == 0
    entropy = -(probs * jax.nn.log_softmax(mask_logits(logits, allowed))).sum()
    assert np.isfinite(entropy)
    full = jax.nn.softmax(logits)[0]
    assert blocked_mass(logits, allowed)[0] == pytest.approx(float(full[1] + full[3]), rel=1e-6)


def test_when_every_action_is_blocked_the_least_risky_stays():
    risk = jnp.array([[0.9, 0.7, 0.8], [0.1, 0.9, 0.2]])
    allowed = np.asarray(allow_least_risky(risk, 0.5))
    assert allowed.tolist() == [[False, True, False], [True, False, True]]


def test_bad_shield_settings_are_refused():
    env = jaxgrid.make("TwoRooms-v0")
    with pytest.raises(ValueError, match="needs a trained checker"):
        make_shield(env, "checker")
    with pytest.raises(ValueError, match=r"threshold must be in \(0, 1\)"):
        make_shield(env, "monitor", threshold=1.0)
    with pytest.raises(ValueError, match="judge must be one of"):
        make_shield(env, "oracle")
    with pytest.raises(ValueError, match="needs a trained checker"):
        make_learner(dataclasses.replace(TINY, reward_mode="shield"))
    for bad in (0.0, 1.0, 1.5):
        with pytest.raises(ValueError, match=r"checker_threshold must be in \(0, 1\)"):
            dataclasses.replace(TINY, checker_threshold=bad)


@pytest.fixture(scope="module")
def lava_states():
    """A batch of TwoRoomsLava states after a few random steps (some next to lava)."""
    env = jaxgrid.make("TwoRoomsLava-v0")

    @fast_jit
    def states(key):
        state, _ = jax.vmap(env.reset)(jax.random.split(key, 64))

        def step(s, k):
            a = jax.random.randint(k, (64,), 0, 3)  # turns and forward: wander
            s, _ = jax.vmap(env.step)(s, a)
            return s, None

        return jax.lax.scan(step, state, jax.random.split(key, 6))[0]

    return env, states(jax.random.PRNGKey(3))


@pytest.mark.parametrize("judged", [None, MOVES])
def test_candidates_are_the_envs_own_steps(lava_states, judged):
    env, states = lava_states
    shield = make_shield(env, "monitor").replace(judged=judged)
    cand_states, cand_ts = fast_jit(shield.candidates)(states)
    assert len(shield.actions) == (env.num_actions if judged is None else len(MOVES))
    for i, a in enumerate(shield.actions):
        want_states, want_ts = fast_jit(jax.vmap(env.step))(states, jnp.full((64,), a))
        got = jax.tree.map(lambda x, i=i: x[:, i], (cand_states, cand_ts))
        for x, y in zip(jax.tree.leaves(got), jax.tree.leaves((want_states, want_ts)), strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("env_id", ["TwoRoomsLava-v0", "HazardRooms-v0"])
def test_only_a_move_can_violate_so_the_monitor_judges_moves_alone(env_id):
    """From states next to hazards, the monitor judging every action flags a move and never
    anything else, so judging only the moves (the default) gives the same risks."""
    env = jaxgrid.make(env_id)

    @fast_jit
    def risks(key):
        state, _ = jax.vmap(env.reset)(jax.random.split(key, 128))

        def step(s, k):
            s, _ = jax.vmap(env.step)(s, jax.random.randint(k, (128,), 0, env.num_actions))
            every = make_shield(env, "monitor").replace(judged=None).risk(s, None, None)
            return s, (every, make_shield(env, "monitor").risk(s, None, None))

        return jax.lax.scan(step, state, jax.random.split(key, 24))[1]

    every, moves = risks(jax.random.PRNGKey(4))
    assert make_shield(env, "monitor").judged == MOVES
    assert float(every[..., MOVES].sum()) >= 20  # the states do lead into hazards
    np.testing.assert_array_equal(np.asarray(every), np.asarray(moves))


def test_checker_judge_scores_the_raw_window_ending_at_each_candidate(lava_states, tiny_checker):
    """Risk of action a = the checker on (last n-1 raw frames, candidate observation of a)."""
    env, states = lava_states
    shield = make_shield(env, "checker", tiny_checker)
    n = tiny_checker.config.window
    rng = np.random.default_rng(0)
    older = jnp.asarray(rng.integers(0, 11, (64, n - 1, 5, 5, 3)), jnp.uint8)
    tokens = fast_jit(jax.vmap(env.observe))(states)["constraint"]
    frames = tiny_checker.embed_states(older)
    risk = fast_jit(shield.risk)(states, frames, tiny_checker.encode_language(tokens))
    _, cand = fast_jit(shield.candidates)(states)
    for a in range(env.num_actions):
        window = jnp.concatenate([older, cand.observation["image"][:, a, None]], axis=1)
        want = creward.violation_prob(tiny_checker, window, tokens)
        np.testing.assert_allclose(risk[:, a], want, atol=1e-5)
    assert np.ptp(np.asarray(risk)) > 1e-3


def test_monitor_shield_lets_no_violation_through():
    """A random policy in TwoRooms-Lava violates often; behind the monitor shield, never
    (here some action is always safe: turning in place)."""
    env = jaxgrid.make("TwoRoomsLava-v0")
    shield = make_shield(env, "monitor")

    def random_act(obs, key, allowed=None):
        logits = jnp.zeros((obs["direction"].shape[0], env.num_actions))
        logits = logits.at[:, 2].set(2.0)  # mostly forward: into lava when it is ahead
        return jax.random.categorical(
            key, logits if allowed is None else mask_logits(logits, allowed)
        )

    key = jax.random.PRNGKey(0)
    off = fast_jit(lambda k: play_episodes(env, random_act, k, 64))(key)
    on = fast_jit(lambda k: play_episodes(env, random_act, k, 64, shield=shield))(key)
    assert off["violations"].sum() >= 10
    assert on["violations"].sum() == 0


@pytest.fixture(scope="module")
def monitor_rollout():
    config = dataclasses.replace(TINY, env_id="TwoRoomsLava-v0", reward_mode="shield_monitor")
    learner = make_learner(config)

    @fast_jit
    def go(key):
        runner = learner.init(key)
        _, traj, stats, batch = learner.collect(runner, key)
        return runner, traj, stats, batch

    return learner, go(jax.random.PRNGKey(1))


def test_shielded_rollout_acts_only_allowed_actions(monitor_rollout):
    _, (_, traj, stats, _) = monitor_rollout
    allowed = np.asarray(traj.allowed)
    taken = np.take_along_axis(allowed, np.asarray(traj.action)[..., None], axis=-1)[..., 0]
    assert taken.all()
    assert int(stats["violations"].sum()) == 0
    assert int(stats["blocked"].sum()) == int((~allowed).sum())


def test_ppo_ratio_uses_the_mask_the_policy_acted_with(monitor_rollout):
    """Before any update the ratio is 1 (approx. KL 0) only with the stored mask applied."""
    learner, (runner, traj, _, batch) = monitor_rollout
    assert (~np.asarray(traj.allowed)).any()  # the shield did block something

    def loss(b):
        policy = lambda p, *x: learner.forward(p, b)  # noqa: E731
        return ppo_loss(policy, runner.params, b, runner.lagrange, learner.config, 1.0)[1]

    with_mask = fast_jit(loss)(batch)
    without = fast_jit(loss)({k: v for k, v in batch.items() if k != "allowed"})
    assert abs(float(with_mask["approx_kl"])) < 1e-6
    assert float(without["approx_kl"]) > 1e-4
    assert float(with_mask["blocked_prob"]) > 0
