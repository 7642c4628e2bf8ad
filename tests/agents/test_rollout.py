"""``agents.rollout`` through ``Learner.rollout``: the rollout replays the env; the ring
buffer of checker embeddings equals :func:`checker.reward.violation_prob` on raw frames; the
checker and shaped rewards; the novelty bonus; the truncation bootstrap.

Each test steps a learner whose configuration has ``num_steps=1``: chaining its one-step
``Learner.rollout`` exposes the environment carry after every step, which the reference
replays need, while the step itself is the learner's own.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.agents_cases import CHECKER_CONFIG, TINY, fast_jit
from jax import lax

import checker.reward as creward
from agents import checker_carry, rollout
from agents.networks import ActorCritic
from agents.train import make_learner
from jaxgrid.constants import FORWARD
from jaxgrid.wrappers import AutoReset, masked_map

ROLL_STEPS = 10
SHORT = (("max_steps", 4),)  # episodes truncate every 4 steps: several auto-resets
ONE_STEP = dict(num_steps=1)


def step_by_step(learner, runner, steps=ROLL_STEPS):
    """``steps`` chained one-step rollouts from ``runner`` (``num_steps == 1``): the
    transitions (T, E) and the environment carry after each step."""
    assert learner.config.num_steps == 1

    @fast_jit
    def go(runner):
        lang = learner.lang_table(runner.params)

        def step(env, key):
            env, transition, _ = learner.rollout(runner.replace(env=env), key, lang)
            return env, (jax.tree.map(lambda x: x[0], transition), env)

        _, out = lax.scan(step, runner.env, jax.random.split(runner.key, steps))
        return out

    return jax.device_get(go(runner))


def make_reference(env, network, window):
    """Replays the learner's actions with ``vmap(AutoReset(env))`` and a raw frame buffer.

    Per step: the env reward, violation, termination flags, the raw window that ends at the
    step's observation (the finished episode's last one where the step ended it), the
    checker's :func:`checker.reward.violation_prob` on it with that episode's tokens, the
    critic's value of the final observation (sentence features from the tokens, not the
    learner's table) and the raw buffer after :func:`checker.reward.push` of the returned
    observation (cleared on auto-reset).
    """
    auto = AutoReset(env)

    @fast_jit
    def replay(params, chk, carry0, actions):
        n = carry0.obs["direction"].shape[0]
        buf = creward.push(
            creward.init_buffer(n, window, env.view_size), carry0.obs["image"], jnp.ones(n, bool)
        )

        def step(carry, action):
            state, obs, buf = carry
            state, ts = jax.vmap(auto.step)(state, action)
            final = ts.info["final_observation"]
            done = ts.terminated | ts.truncated
            tokens = obs["constraint"]
            window_buf = creward.push(buf, final["image"], jnp.zeros(n, bool))
            prob = creward.violation_prob(chk, window_buf, tokens)
            lang = network.apply(params, tokens, method=ActorCritic.sentence_features)
            _, v_final, _ = network.apply(params, final["image"], final["direction"], lang)
            buf = creward.push(buf, ts.observation["image"], done)
            out = dict(
                reward=ts.reward, violation=ts.info["violation"], terminated=ts.terminated,
                truncated=ts.truncated, prob=prob, v_final=v_final, buf=buf,
                obs_image=ts.observation["image"], final_image=final["image"],
            )  # fmt: skip
            return (state, ts.observation, buf), out

        _, out = lax.scan(step, (carry0.state, carry0.obs, buf), actions)
        return out

    return replay


@pytest.fixture(scope="module")
def rollouts(tiny_checker):
    """Checker-mode and shaped-mode learners stepped from one initial state, and a replay."""
    checker_cfg = dataclasses.replace(
        TINY, env_kwargs=SHORT, reward_mode="checker", penalty=0.7, gamma=0.9, **ONE_STEP
    )
    shaped_cfg = dataclasses.replace(
        TINY, env_kwargs=SHORT, reward_mode="shaped", penalty=0.7, **ONE_STEP
    )
    checker_learner = make_learner(checker_cfg, tiny_checker)
    shaped_learner = make_learner(shaped_cfg)
    runner0 = fast_jit(checker_learner.init)(jax.random.PRNGKey(3))
    replay = make_reference(checker_cfg.make_env(), checker_learner.network, CHECKER_CONFIG.window)
    out = {}
    for name, learner in (("checker", checker_learner), ("shaped", shaped_learner)):
        transitions, carries = step_by_step(learner, runner0)
        ref = jax.device_get(replay(runner0.params, tiny_checker, runner0.env, transitions.action))
        out[name] = (learner, transitions, carries, ref)
    return runner0, out


def test_rollout_replays_the_env(rollouts):
    _, out = rollouts
    for name, (_, tr, carries, ref) in out.items():
        np.testing.assert_array_equal(carries.obs["image"], ref["obs_image"], err_msg=name)
        np.testing.assert_array_equal(tr.done, ref["terminated"] | ref["truncated"])
        # The scenario under test happens: auto-resets on truncation, within the rollout.
        assert ref["truncated"].sum() >= 8 and not ref["terminated"].all()


def test_checker_embedding_ring_buffer_matches_raw_frames(rollouts, tiny_checker):
    """The learner's buffer of embeddings and probabilities equal the raw-frame pipeline."""
    runner0, out = rollouts
    learner, tr, carries, ref = out["checker"]
    # Frames carried by the learner: embeddings of the last n-1 raw frames, across resets.
    embed = fast_jit(tiny_checker.embed_states)
    np.testing.assert_allclose(carries.frames, embed(ref["buf"][:, :, 1:]), atol=1e-5)
    # Probabilities from the learner's embedding window vs violation_prob on raw frames.
    frames_before = np.concatenate([runner0.env.frames[None], carries.frames[:-1]])
    sentence_before = np.concatenate([runner0.env.sentence[None], carries.sentence[:-1]])
    codes = tiny_checker.encode_language(learner.table[:, : learner.words])
    logit = fast_jit(jax.vmap(lambda f, e, s: tiny_checker.stream_step(f, e, codes[s])[0]))(
        frames_before, embed(ref["final_image"]), sentence_before
    )
    prob = jax.nn.sigmoid(logit)
    np.testing.assert_allclose(prob, ref["prob"], atol=1e-5)
    assert np.ptp(ref["prob"]) > 1e-3  # a random checker still gives varied probabilities


def test_checker_embeds_only_the_masked_rows_with_the_same_bits(tiny_checker):
    """``masked_map`` of the embedding (the first frames of new episodes) equals embedding
    every row and selecting, bit for bit: no row, a few rows, more rows than one chunk, and
    under vmap."""
    embed = functools.partial(checker_carry.embed, tiny_checker)
    rng = np.random.default_rng(0)
    images = jnp.asarray(rng.integers(0, 11, (3, 40, 5, 5, 3)), jnp.uint8)
    other = jnp.asarray(rng.normal(size=(3, 40, CHECKER_CONFIG.state_dim)), jnp.float32)
    masks = np.zeros((3, 40), bool)
    masks[1, [3, 17, 38]] = True
    masks[2, rng.permutation(40)[:37]] = True  # three chunks of 16
    dense = fast_jit(lambda m, i, o: jnp.where(m[:, None], embed(i), o))
    sparse = fast_jit(functools.partial(masked_map, fn=embed))
    for m, i, o in zip(masks, images, other, strict=True):
        np.testing.assert_array_equal(sparse(m, inputs=i, other=o), dense(m, i, o))
    batched = fast_jit(jax.vmap(lambda m, i, o: masked_map(m, embed, i, o)))(masks, images, other)
    np.testing.assert_array_equal(batched, jax.vmap(dense)(masks, images, other))


def test_checker_and_shaped_rewards(rollouts):
    _, out = rollouts
    for name, (learner, tr, _, ref) in out.items():
        c = learner.config
        bootstrap = c.gamma * (ref["truncated"] & ~ref["terminated"]) * ref["v_final"]
        if name == "checker":
            prob = ref["prob"]
            clear = np.abs(prob - c.checker_threshold) > 1e-4  # no ties at the threshold
            assert clear.mean() > 0.9
            alarm = (prob > c.checker_threshold).astype(np.float32)
            expected = ref["reward"] - c.penalty * alarm + bootstrap
            np.testing.assert_allclose(tr.reward[clear], expected[clear], atol=1e-5)
        else:
            expected = ref["reward"] - c.penalty * ref["violation"] + bootstrap
            np.testing.assert_allclose(tr.reward, expected, atol=1e-5)
        # Truncated steps carry gamma * V(final observation): the bootstrap is really there.
        assert np.abs(bootstrap).max() > 1e-3


@pytest.mark.parametrize(
    "changes,carrying",
    [pytest.param(False, True, marks=pytest.mark.slow), (True, True),
     pytest.param(False, False, marks=pytest.mark.slow)],
    ids=["visits", "visits_and_changes", "cells_only"],
)  # fmt: skip
def test_novelty_bonus_pays_first_visits_per_episode(rollouts, changes, carrying):
    """The bonus is the reward difference against the same rollout without it (the shaped
    learner of ``rollouts``: same params and keys, so the same actions), and equals a host
    replay of episodic first visits (and, with ``novelty_changes``, first changes of a
    cell; without ``novelty_carrying``, of cells whatever is carried)."""
    runner, out = rollouts
    plain, tr0, _, _ = out["shaped"]
    config = dataclasses.replace(
        plain.config, novelty_bonus=0.5, novelty_changes=changes, novelty_carrying=carrying
    )
    bonus = make_learner(config)
    tr1, carry1 = step_by_step(bonus, fast_jit(bonus.init)(jax.random.PRNGKey(3)))
    np.testing.assert_array_equal(tr0.action, tr1.action)
    got = tr1.reward - tr0.reward

    def visit(state, t, e):
        x, y = state.agent_pos[t, e] if t is not None else state.agent_pos[e]
        carrying = state.carrying[t, e, 0] if t is not None else state.carrying[e, 0]
        return int(x), int(y), bool(carrying != 1) and config.novelty_carrying

    start = jax.device_get(runner.env.state)
    grids = np.concatenate([start.grid[None], carry1.state.grid])  # (T + 1, E, W, H, 3)
    expected = np.zeros_like(got)
    for e in range(got.shape[1]):
        seen, changed = {visit(start, None, e)}, set()
        for t in range(got.shape[0]):
            cell = visit(carry1.state, t, e)
            if tr1.done[t, e]:
                seen, changed = {cell}, set()  # the returned state starts the next episode
                continue
            expected[t, e] = 0.5 * (cell not in seen)
            seen.add(cell)
            if changes:
                diff = {tuple(xy) for xy in np.argwhere((grids[t, e] != grids[t + 1, e]).any(-1))}
                expected[t, e] += 0.5 * len(diff - changed)
                changed |= diff
    np.testing.assert_allclose(got, expected, atol=1e-6)
    assert 0 < (expected > 0).mean() < 1  # both first visits and revisits happen
    assert tr1.done.any()  # and episodes restart within the rollout


@pytest.mark.slow
def test_novelty_claim_caps_the_bonus_and_pays_the_rest_at_the_goal():
    """``novelty_claim`` K: against the same rollout without the bonus, an episode is paid for
    new (cell, carrying) pairs until it has visited K (its start included), and the step that
    reaches the goal is paid for the rest, so each successful episode earns the same K - 1."""
    claim = 4
    base = dataclasses.replace(
        TINY, env_id="MiniGrid-Empty-5x5-v0", env_kwargs=(("max_steps", 200),), num_envs=32,
        **ONE_STEP,
    )  # fmt: skip
    plain = make_learner(base)
    bonus = make_learner(dataclasses.replace(base, novelty_bonus=0.5, novelty_claim=claim))
    runner = fast_jit(plain.init)(jax.random.PRNGKey(5))
    tr0, _ = step_by_step(plain, runner, steps=80)
    tr1, carry1 = step_by_step(bonus, fast_jit(bonus.init)(jax.random.PRNGKey(5)), steps=80)
    np.testing.assert_array_equal(tr0.action, tr1.action)
    got = tr1.reward - tr0.reward
    start = jax.device_get(runner.env.state)
    expected, earned = np.zeros_like(got), []
    for e in range(got.shape[1]):
        seen = {tuple(start.agent_pos[e])}
        for t in range(got.shape[0]):
            left = max(claim - len(seen), 0)
            if tr1.done[t, e]:  # no time limit within the rollout: every end is the goal
                expected[t, e] = 0.5 * left
                earned.append(0.5 * (len(seen) - 1) + expected[t, e])
                seen = {tuple(carry1.state.agent_pos[t, e])}
                continue
            cell = tuple(carry1.state.agent_pos[t, e])
            expected[t, e] = 0.5 * (cell not in seen and left > 0)
            seen.add(cell)
    np.testing.assert_allclose(got, expected, atol=1e-6)
    assert len(earned) >= 3  # episodes reach the goal within the rollout
    # Each of them earned K - 1 bonuses (the start pays none), whatever its route.
    np.testing.assert_allclose(earned, 0.5 * (claim - 1), atol=1e-6)
    with pytest.raises(ValueError, match="novelty_claim"):
        dataclasses.replace(base, novelty_claim=3)  # no bonus to pay out
    with pytest.raises(ValueError, match="novelty_claim"):
        dataclasses.replace(base, novelty_bonus=0.1, novelty_claim=-1)


@pytest.mark.slow
def test_novelty_changes_pay_each_cell_once_per_episode():
    """``visits``/``novel`` on hand-made states: an episode's start has nothing changed, a
    door that opens pays once, and opening it again (or a revisit) pays nothing."""
    env = TINY.make_env()
    w, h = env.width, env.height
    state, _ = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    seen = rollout.visits(state, w, h, True, True)
    assert seen.shape == (2, w * h * 3) and not seen[:, w * h * 2 :].any()
    door = state.replace(grid=state.grid.at[0, 3, 2, 2].set(7))  # env 0: cell (3, 2) changes
    hit = rollout.visits(door, w, h, True, True, before=state)
    np.testing.assert_array_equal(rollout.novel(seen, hit, w, h), [1.0, 0.0])  # pos revisited
    seen = seen | hit
    again = rollout.visits(door, w, h, True, True, before=state)
    np.testing.assert_array_equal(rollout.novel(seen, again, w, h), [0.0, 0.0])
    off = rollout.visits(door, w, h, False, True, before=state)
    np.testing.assert_array_equal(rollout.novel(off[:, :1], off, w, h), [0.0, 0.0])


@pytest.mark.slow  # a novelty variant of its own compile; the default bonus is tested above
def test_novelty_without_carrying_pays_cells_only():
    """With ``carrying=False`` (``PPOConfig.novelty_carrying``) a cell walked again with an
    object in hand is not new; with the default (cell, carrying) pairs it is."""
    env = TINY.make_env()
    w, h = env.width, env.height
    state, _ = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 2))
    held = state.replace(carrying=state.carrying.at[0].set(jnp.array([5, 4, 0], jnp.uint8)))
    for carrying, expected in ((True, [1.0, 0.0]), (False, [0.0, 0.0])):
        seen = rollout.visits(state, w, h, True, carrying=carrying)
        hit = rollout.visits(held, w, h, True, carrying=carrying)  # env 0 picked up a key
        np.testing.assert_array_equal(rollout.novel(seen, hit, w, h), expected)


def test_terminal_step_on_the_time_limit_is_not_bootstrapped():
    """LavaGap with max_steps=1: every step truncates; stepping into lava also terminates."""
    config = dataclasses.replace(
        TINY, env_id="MiniGrid-LavaGapS5-v0", env_kwargs=(("max_steps", 1),), num_envs=16,
        **ONE_STEP,
    )  # fmt: skip
    learner = make_learner(config)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(1))
    tr, carries = step_by_step(learner, runner, steps=8)

    @fast_jit
    def values_of_final(runner, actions):
        auto = AutoReset(config.make_env())
        policy = learner.policy(runner.params, learner.lang_table(runner.params))

        def step(state, action):
            state, ts = jax.vmap(auto.step)(state, action)
            final = ts.info["final_observation"]
            sentence = jnp.zeros(action.shape, jnp.int32)
            _, v, _, _ = policy(final["image"], final["direction"], sentence, runner.env.memory)
            return state, (ts.reward, ts.terminated, ts.truncated, v)

        return lax.scan(step, runner.env.state, actions)[1]

    reward, terminated, truncated, v_final = jax.device_get(values_of_final(runner, tr.action))
    assert truncated.all() and tr.done.all()
    both = terminated & truncated
    assert both.sum() >= 3, "some steps should walk into the lava"
    np.testing.assert_array_equal(tr.reward[both], reward[both])  # terminal: no bootstrap
    only = truncated & ~terminated
    np.testing.assert_allclose(
        tr.reward[only], reward[only] + config.gamma * v_final[only], rtol=1e-5, atol=1e-6
    )


def _alarm_replay(rollouts, tiny_checker, **flags):
    """The checker rollout again with ``flags`` and the threshold at the median probability
    (about half the steps alarm): ``(config, transitions, ref, alarm, alarmed before)``, where
    "before" means the episode's previous step alarmed (a fresh episode starts without one)."""
    runner0, out = rollouts
    learner, _, _, ref = out["checker"]
    threshold = float(np.median(ref["prob"]))
    c = dataclasses.replace(learner.config, checker_threshold=threshold, **flags)
    tr, _ = step_by_step(make_learner(c, tiny_checker), runner0)
    np.testing.assert_array_equal(tr.action, out["checker"][1].action)  # the same steps
    alarm = ref["prob"] > threshold
    done = ref["terminated"] | ref["truncated"]
    before = np.concatenate([np.zeros_like(alarm[:1]), (alarm & ~done)[:-1]])
    return c, tr, ref, alarm, before


def _assert_charged(c, tr, ref, charged, prob):
    """Rewards are the env's minus the penalty where ``charged``, plus the bootstrap; steps
    whose deciding ``prob`` sits at the threshold are skipped (float noise decides them)."""
    bootstrap = c.gamma * (ref["truncated"] & ~ref["terminated"]) * ref["v_final"]
    expected = ref["reward"] - c.penalty * charged + bootstrap
    clear = np.abs(prob - c.checker_threshold) > 1e-4
    np.testing.assert_allclose(tr.reward[clear], expected[clear], atol=1e-5)


def test_alarm_onset_penalises_only_the_step_that_raises_the_alarm(rollouts, tiny_checker):
    c, tr, ref, alarm, before = _alarm_replay(rollouts, tiny_checker, alarm_onset=True)
    assert (alarm & before).sum() >= 5  # repeated alarms happen, and are not penalised
    _assert_charged(c, tr, ref, alarm & ~before, ref["prob"])


def test_alarm_forward_charges_the_next_forward_step(rollouts, tiny_checker):
    """With ``alarm_forward`` a step is penalised iff the episode's previous step alarmed and
    this one moves forward."""
    c, tr, ref, alarm, before = _alarm_replay(rollouts, tiny_checker, alarm_forward=True)
    charged = before & (tr.action == FORWARD)
    assert charged.sum() >= 3 and (alarm & (tr.action != FORWARD)).sum() >= 3
    prev_prob = np.concatenate([np.full_like(ref["prob"][:1], 1.0), ref["prob"][:-1]])
    _assert_charged(c, tr, ref, charged, prev_prob)
    with pytest.raises(ValueError, match="alarm_forward"):
        dataclasses.replace(c, alarm_onset=True)


def test_the_monitor_cost_is_a_constrained_modes_cost():
    """With ``cost_source="monitor"`` the Lagrangian's cost is the monitor's ``info["cost"]``
    of each step (the replayed env's; plus the truncation bootstrap where an episode was
    cut), with no checker at all."""
    config = dataclasses.replace(
        TINY, env_id="TwoRoomsLava-v0", env_kwargs=(("max_steps", 8),), num_envs=16,
        num_steps=64, total_timesteps=16 * 64 * 2, reward_mode="lagrangian",
        cost_source="monitor",
    )  # fmt: skip
    learner = make_learner(config)
    assert learner.checker is None
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))
    _, traj, stats = jax.device_get(fast_jit(learner.rollout)(runner, runner.key))
    auto = AutoReset(config.make_env())

    @fast_jit
    def replay(state, actions):
        def step(state, action):
            state, ts = jax.vmap(auto.step)(state, action)
            return state, (ts.info["cost"], ts.truncated & ~ts.terminated)

        return lax.scan(step, state, actions)[1]

    cost, cut = jax.device_get(replay(runner.env.state, traj.action))
    assert cost.sum() >= 2 and cut.any()  # costly steps and cut episodes both happen
    np.testing.assert_array_equal(traj.cost[~cut], cost[~cut])
    np.testing.assert_array_equal(stats["cost"], cost.sum(axis=1))
    assert stats["alarms"].sum() == 0
