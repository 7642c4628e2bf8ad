"""Tests of the fused PPO learner (``agents``): configuration errors, vmapped training over
seeds, compile-once updates, GAE and the truncation bootstrap, the checker's ring buffer of
embeddings against :func:`checker.reward.violation_prob` on raw frames, the reward modes,
the Lagrangian multiplier, the runner's logs, checkpoints, resume and non-finite guard, the
sharded multi-device run, and the evaluation protocol.

Configurations are tiny (8 envs, 8 steps, 4 updates) so that the file runs on 2 CPU cores;
compiled programs are shared through module-scoped fixtures, and :func:`agents.runner.run`
keeps its compiled programs between calls with the same configuration.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

import checker.reward as creward
import jaxgrid
from agents import runner as runner_mod
from agents.evaluation import play_episodes, summarise
from agents.networks import ActorCritic
from agents.ppo import Learner, PPOConfig, make_learner, make_train, masked_map, shuffle
from agents.runner import NonFiniteError, run
from checker.model import CheckerConfig
from checker.trained import TrainedChecker, new_checker
from jaxgrid.oracle import oracle_action
from jaxgrid.wrappers import AutoReset

ROOT = Path(__file__).resolve().parents[1]

# 8 envs x 8 steps, 4 updates in 2 chunks of 2, one epoch of 2 minibatches.
TINY = PPOConfig(
    num_envs=8, num_steps=8, total_timesteps=8 * 8 * 4, update_epochs=1, num_minibatches=2,
    eval_every=2, eval_episodes=4, penalty_start=0.0, penalty_warmup=0.0,
)  # fmt: skip
# A small checker (window of 3 frames) with the scenarios' 5x5 view.
CHECKER_CONFIG = CheckerConfig(
    window=3, word_dim=8, gru_dim=16, state_dim=16, cell_dim=4, conv_channels=4,
    temporal_channels=8, mlp_dim=16, mlp_layers=1,
)  # fmt: skip
SEEDS = (0, 1)
# Programs built only for these tests compile with LLVM's optimisations off: about half the
# compile time on 2 CPU cores, same semantics. agents.runner.run compiles as in production.
FAST = {"xla_backend_optimization_level": 0}
fast_jit = functools.partial(jax.jit, compiler_options=FAST)


def keys_of(*seeds):
    return jnp.stack([jax.random.PRNGKey(s) for s in seeds])


def leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(tree)]


@pytest.fixture(scope="module")
def tiny_checker():
    return new_checker(CHECKER_CONFIG, jax.random.PRNGKey(7), env_id="TwoRooms-v0")


# ------------------------------------------------------------------ multi-device process
# Slow (about 45 s of CPU on its own): a fresh process with 4 host devices compiles the
# sharded programs. When the test is selected, the process starts with the module, so that
# its compilation overlaps the other tests; the comparison is the last test.
MULTI_DEVICE_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import jax
    import numpy as np
    from agents.ppo import PPOConfig
    from agents.runner import run

    config = PPOConfig(**json.loads(sys.argv[1]))
    out = sys.argv[2]
    assert len(jax.devices()) == 4, jax.devices()
    bad = {}
    try:
        run(PPOConfig(**{**json.loads(sys.argv[1]), "num_envs": 6}), progress=False)
    except ValueError as e:
        bad["error"] = str(e)
    result = run(config, seeds=(0, 1), progress=False, out_dir=out + "/run")
    env_leaf = jax.tree.leaves(result["runner"].env)[0]
    np.savez(out + "/params.npz", *[np.asarray(x) for x in jax.tree.leaves(result["params"])])
    json.dump({
        "bad": bad,
        "eval": {k: v.tolist() for k, v in result["eval"].items()},
        "train_violations": result["train_violations"].tolist(),
        "env_devices": len(env_leaf.sharding.device_set),
        "env_shard_shape": list(env_leaf.sharding.shard_shape(env_leaf.shape)),
        "env_shape": list(env_leaf.shape),
    }, open(out + "/result.json", "w"))
    """
)


MULTI_DEVICE_TEST = "test_multi_device_run_matches_single_device"


def _config_json(config: PPOConfig) -> str:
    return json.dumps({k: v for k, v in dataclasses.asdict(config).items()})


@pytest.fixture(scope="module", autouse=True)
def multi_device_process(request, tmp_path_factory):
    if not any(item.name == MULTI_DEVICE_TEST for item in request.session.items):
        yield None
        return
    out = tmp_path_factory.mktemp("multi_device")
    env = {
        **os.environ,
        "XLA_FLAGS": "--xla_force_host_platform_device_count=4 --xla_backend_optimization_level=0",
        "JAX_PLATFORMS": "cpu",
        "PYTHONPATH": str(ROOT),
    }
    proc = subprocess.Popen(
        [sys.executable, "-c", MULTI_DEVICE_SCRIPT, _config_json(TINY), str(out)],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    yield proc, out
    if proc.poll() is None:
        proc.kill()
        proc.communicate()


# ------------------------------------------------------------------------ 1. validation
@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(num_envs=0), "num_envs"),
        (dict(num_steps=-1), "num_steps"),
        (dict(total_timesteps=0), "total_timesteps"),
        (dict(update_epochs=0), "update_epochs"),
        (dict(num_minibatches=0), "num_minibatches"),
        (dict(eval_every=0), "eval_every"),
        (dict(eval_episodes=0), "eval_episodes"),
        (dict(num_envs=2.5), "num_envs"),
        (dict(num_minibatches=3), "num_minibatches"),  # 64 steps per update
        (dict(num_envs=6, num_steps=4, num_minibatches=4), "num_minibatches"),
        (dict(total_timesteps=8 * 8), "total_timesteps"),  # 1 update < eval_every
        (dict(reward_mode="penalty"), "reward_mode"),
        (dict(gamma=1.5), "gamma"),
        (dict(gamma=-0.1), "gamma"),
        (dict(gae_lambda=1.01), "gae_lambda"),
        (dict(lr=0.0), "lr"),
        (dict(lr=float("nan")), "lr"),
        (dict(clip_eps=-0.2), "clip_eps"),
        (dict(checker_threshold=2.0), "checker_threshold"),
        (dict(penalty=-1.0), "penalty"),
        (dict(lagrangian_init=-1.0), "lagrangian_init"),
        (dict(conv_channels=(16, 0)), "conv_channels"),
        (dict(conv_channels=16), "conv_channels"),
        (dict(env_kwargs=(("max_steps", [3]),)), "env_kwargs"),
    ],
)
def test_config_rejects_bad_values(kwargs, field):
    with pytest.raises(ValueError, match=field):
        dataclasses.replace(TINY, **kwargs)


def test_mlp_view_encoder_option():
    """``conv_channels=()`` builds the policy without the convolution and still trains."""
    config = dataclasses.replace(TINY, conv_channels=[])
    assert config.conv_channels == () and hash(config) != hash(TINY)
    learner = make_learner(config)
    assert learner.network.conv_channels == ()
    runner = learner.init(jax.random.PRNGKey(0))
    assert not any("convs" in jax.tree_util.keystr(p) for p, _ in
                   jax.tree_util.tree_leaves_with_path(runner.params))  # fmt: skip
    runner, metrics = jax.jit(learner.update)(runner)
    assert np.isfinite(float(metrics["loss"])) and int(runner.update) == 1


def test_config_accepts_edges_and_normalises_env_kwargs():
    assert dataclasses.replace(TINY, gamma=0.0, gae_lambda=1.0).gamma == 0.0
    a = dataclasses.replace(TINY, env_kwargs={"max_steps": 4, "view_size": 5})
    b = dataclasses.replace(TINY, env_kwargs=(("view_size", 5), ("max_steps", 4)))
    assert a == b and hash(a) == hash(b)
    assert a.make_env().max_steps == 4


def test_bad_env_and_checker_fail_before_compiling(monkeypatch):
    wide = TrainedChecker(params={}, config=dataclasses.replace(CHECKER_CONFIG, view_size=7))

    def no_compile(*args, **kwargs):
        raise AssertionError("compiled before validating")

    monkeypatch.setattr(jax, "jit", no_compile)
    for mode in ("checker", "lagrangian"):
        config = dataclasses.replace(TINY, reward_mode=mode)
        for build in (make_learner, make_train):
            with pytest.raises(ValueError, match="reward_mode='" + mode):
                build(config)
        with pytest.raises(ValueError, match="needs a trained checker"):
            run(config, progress=False)
    with pytest.raises(ValueError, match="no setting 'max_stepz'"):
        make_learner(dataclasses.replace(TINY, env_kwargs=(("max_stepz", 3),)))
    with pytest.raises(ValueError, match="view_size"):
        make_learner(dataclasses.replace(TINY, reward_mode="checker"), wide)
    with pytest.raises(ValueError, match="distinct"):
        run(TINY, seeds=(1, 1), progress=False)


def test_mesh_rejects_indivisible_env_batch(monkeypatch):
    fake = [jax.devices()[0]] * 4
    monkeypatch.setattr(jax, "local_devices", lambda: fake)
    with pytest.raises(ValueError, match=r"num_envs \(6\).*number of devices \(4\)"):
        runner_mod._mesh(6)
    monkeypatch.setattr(jax, "local_devices", lambda: fake[:1])
    assert runner_mod._mesh(6) is None


# ------------------------------------------------- 2 + 6. vmapped training, Lagrangian
LAGRANGIAN = dataclasses.replace(
    TINY, reward_mode="lagrangian", checker_threshold=0.0, cost_target=0.25, lagrangian_lr=0.1
)


@pytest.fixture(scope="module")
def lagrangian_train(tiny_checker):
    train = fast_jit(jax.vmap(make_train(LAGRANGIAN, tiny_checker)))
    first = jax.device_get(train(keys_of(*SEEDS)))
    again = jax.device_get(train(keys_of(*SEEDS)))
    return first, again


def test_vmapped_train_over_seeds(lagrangian_train):
    out, again = lagrangian_train
    n, k = LAGRANGIAN.num_chunks, LAGRANGIAN.eval_every
    assert out["train"]["loss"].shape == (2, n, k)
    for name, value in out["eval"].items():
        assert value.shape == (2, n), name
    for path, x in jax.tree_util.tree_leaves_with_path(out):
        if np.issubdtype(np.asarray(x).dtype, np.floating):
            assert np.all(np.isfinite(x)), jax.tree_util.keystr(path)
    assert np.all(out["runner"].update == LAGRANGIAN.num_updates)
    assert np.all(out["train"]["episodes"] >= 0)
    # Different seeds, different agents; the same seed, bit-identical results (CPU).
    params = out["runner"].params
    assert any(not np.array_equal(x[0], x[1]) for x in jax.tree.leaves(params))
    for a, b in zip(leaves(out), leaves(again), strict=True):
        np.testing.assert_array_equal(a, b)


def test_lagrange_multiplier_rises_with_cost(lagrangian_train):
    out, _ = lagrangian_train
    t = out["train"]
    cost = t["cost_rate"].reshape(2, -1)
    episode_cost = t["episode_cost"].reshape(2, -1)
    lam = t["lagrange"].reshape(2, -1)
    # Threshold 0: every step raises an alarm, so the cost rate is 1 and the cost per finished
    # episode is the rollout's steps over its episodes, far above cost_target.
    np.testing.assert_allclose(cost, 1.0)
    episodes = t["episodes"].reshape(2, -1)
    np.testing.assert_allclose(
        episode_cost, LAGRANGIAN.batch_size / np.maximum(episodes, 1), rtol=1e-6
    )
    prev = np.concatenate([np.full((2, 1), LAGRANGIAN.lagrangian_init), lam[:, :-1]], axis=1)
    step = LAGRANGIAN.lagrangian_lr * (episode_cost - LAGRANGIAN.cost_target)
    expected = np.maximum(0.0, prev + step)
    np.testing.assert_allclose(lam, expected, rtol=1e-6)
    assert np.all(np.diff(lam, axis=1) > 0) and np.all(lam[:, 0] > 0)
    assert np.all(t["alarms"] == LAGRANGIAN.batch_size)
    assert np.all(np.asarray(out["runner"].lagrange) == lam[:, -1])


def test_lagrange_multiplier_waits_for_penalty_start(tiny_checker):
    """Before ``penalty_start`` the multiplier stays at ``lagrangian_init``; then it moves."""
    # penalty=0: the multiplier follows the schedule, not the shaping penalty's size.
    config = dataclasses.replace(LAGRANGIAN, penalty_start=0.5, penalty=0.0)
    learner = make_learner(config, tiny_checker)
    runner = learner.init(jax.random.PRNGKey(0))
    update = jax.jit(learner.update)
    lams = []
    for _ in range(config.num_updates):
        runner, m = update(runner)
        lams.append(float(m["lagrange"]))
    half = config.num_updates // 2
    assert all(lam == config.lagrangian_init for lam in lams[:half])
    assert lams[-1] > config.lagrangian_init


# ------------------------------------------------------------------------------ 4. GAE
def gae_reference(values, rewards, dones, last_value, gamma, lam):
    adv = np.zeros_like(values)
    gae = np.zeros_like(last_value)
    next_value = last_value
    for t in reversed(range(len(values))):
        not_done = 1.0 - dones[t]
        delta = rewards[t] + gamma * next_value * not_done - values[t]
        gae = delta + gamma * lam * not_done * gae
        adv[t] = gae
        next_value = values[t]
    return adv, adv + values


@pytest.mark.parametrize("n", [1, 2, 1000, 32768, 2**16 + 5])
def test_shuffle_is_a_permutation_set_by_its_key(n):
    draw = jax.jit(shuffle, static_argnums=1)
    perm = np.asarray(draw(jax.random.PRNGKey(0), n))
    assert perm.dtype == np.int32 and np.array_equal(np.sort(perm), np.arange(n))
    np.testing.assert_array_equal(draw(jax.random.PRNGKey(0), n), perm)  # deterministic
    if n > 2:
        assert not np.array_equal(draw(jax.random.PRNGKey(1), n), perm)
        assert not np.array_equal(perm, np.arange(n))


def test_shuffle_spreads_every_item_evenly_over_minibatches():
    """Where each of 64 items lands among 4 minibatches of 16, over 4000 keys: a uniform
    partition puts each item in each minibatch 1000 +- 27 (one s.d.) times."""
    keys = jax.random.split(jax.random.PRNGKey(5), 4000)
    perms = np.asarray(jax.jit(jax.vmap(lambda k: shuffle(k, 64)))(keys))
    where = np.empty_like(perms)
    np.put_along_axis(where, perms, np.arange(64)[None] // 16, axis=1)  # item -> minibatch
    counts = np.stack([(where == m).sum(0) for m in range(4)])  # (minibatch, item)
    assert np.abs(counts - 1000).max() < 5 * 27
    # Neighbouring indices are not kept together (as if the index, not the random bits,
    # ordered the sort).
    together = (where[:, :-1] == where[:, 1:]).mean()
    assert abs(together - 15 / 63) < 0.02


def test_gae_matches_numpy():
    config = dataclasses.replace(TINY, gamma=0.9, gae_lambda=0.8)
    learner = make_learner(config)
    rng = np.random.default_rng(0)
    values = rng.normal(size=(6, 3)).astype(np.float32)
    rewards = rng.normal(size=(6, 3)).astype(np.float32)
    dones = np.zeros((6, 3), bool)
    dones[2, 0] = dones[5, 1] = dones[0, 2] = dones[3, 2] = True
    last = rng.normal(size=3).astype(np.float32)
    adv, target = fast_jit(learner._gae)(values, rewards, dones, last)
    ref_adv, ref_target = gae_reference(values, rewards, dones.astype(np.float32), last, 0.9, 0.8)
    np.testing.assert_allclose(adv, ref_adv, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(target, ref_target, rtol=1e-5, atol=1e-6)
    # Hand-checked entry: env 0 ends at t=2, so its advantage there is r - V (no future).
    np.testing.assert_allclose(adv[2, 0], rewards[2, 0] - values[2, 0], rtol=1e-6)


# --------------------------------------------- 4 + 5. rollouts against a reference replay
ROLL_STEPS = 10
SHORT = (("max_steps", 4),)  # episodes truncate every 4 steps: several auto-resets


def rollout(learner, runner, steps=ROLL_STEPS):
    """``steps`` learner env steps from ``runner``: transitions and the carry after each."""

    @fast_jit
    def go(runner):
        lang = learner._lang_table(runner.params)

        def step(carry, key):
            carry, (transition, _) = learner._env_step(runner.params, lang, carry, key)
            return carry, (transition, carry)

        _, out = lax.scan(step, runner.env, jax.random.split(runner.key, steps))
        return out

    return jax.device_get(go(runner))


def make_reference(env, window):
    """Replays the learner's actions with ``AutoReset(env)`` and a raw frame buffer.

    Per step: the env reward, violation, termination flags, the raw window that ends at the
    step's observation (the finished episode's last one where the step ended it), the
    checker's :func:`checker.reward.violation_prob` on it with that episode's tokens, the
    critic's value of the final observation and the raw buffer after
    :func:`checker.reward.push` of the returned observation (cleared on auto-reset).
    """
    auto = AutoReset(env)
    network = ActorCritic(num_actions=env.num_actions)

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
        TINY, env_kwargs=SHORT, reward_mode="checker", penalty=0.7, gamma=0.9
    )
    shaped_cfg = dataclasses.replace(TINY, env_kwargs=SHORT, reward_mode="shaped", penalty=0.7)
    checker_learner = make_learner(checker_cfg, tiny_checker)
    shaped_learner = make_learner(shaped_cfg)
    runner0 = fast_jit(checker_learner.init)(jax.random.PRNGKey(3))
    replay = make_reference(checker_learner.env, CHECKER_CONFIG.window)
    out = {}
    for name, learner in (("checker", checker_learner), ("shaped", shaped_learner)):
        transitions, carries = rollout(learner, runner0)
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
    prob = fast_jit(jax.vmap(learner._checker_prob))(
        frames_before, embed(ref["final_image"]), sentence_before
    )
    np.testing.assert_allclose(prob, ref["prob"], atol=1e-5)
    assert np.ptp(ref["prob"]) > 1e-3  # a random checker still gives varied probabilities


def test_checker_embeds_only_the_masked_rows_with_the_same_bits(tiny_checker):
    """``masked_map`` of the embedding (the first frames of new episodes) equals embedding
    every row and selecting, bit for bit: no row, a few rows, more rows than one chunk, and
    under vmap."""
    config = dataclasses.replace(TINY, num_envs=40, total_timesteps=40 * 8 * 4,
                                 reward_mode="checker")  # fmt: skip
    learner = make_learner(config, tiny_checker)
    rng = np.random.default_rng(0)
    images = jnp.asarray(rng.integers(0, 11, (3, 40, 5, 5, 3)), jnp.uint8)
    other = jnp.asarray(rng.normal(size=(3, 40, CHECKER_CONFIG.state_dim)), jnp.float32)
    masks = np.zeros((3, 40), bool)
    masks[1, [3, 17, 38]] = True
    masks[2, rng.permutation(40)[:37]] = True  # three chunks of 16
    dense = jax.jit(lambda m, i, o: jnp.where(m[:, None], learner._embed(i), o))
    sparse = jax.jit(functools.partial(masked_map, fn=learner._embed))
    for m, i, o in zip(masks, images, other, strict=True):
        np.testing.assert_array_equal(sparse(m, inputs=i, other=o), dense(m, i, o))
    batched = jax.jit(jax.vmap(lambda m, i, o: masked_map(m, learner._embed, i, o)))(
        masks, images, other
    )
    np.testing.assert_array_equal(batched, jax.vmap(dense)(masks, images, other))


@pytest.mark.parametrize("env_id", ["TwoRooms-v0", "ThreeRoomsKey-v0"])
def test_learner_env_step_equals_auto_reset(env_id):
    """The learner's auto-reset (a fresh episode generated and observed only where one
    ended) gives AutoReset's states and time steps bit for bit, through many resets, all
    envs truncating together included."""
    config = dataclasses.replace(TINY, env_id=env_id, num_envs=24, total_timesteps=24 * 8 * 4)
    learner = make_learner(config)
    env = AutoReset(learner.env)
    states, _ = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 24))

    def run(step):
        def body(carry, key):
            actions = jax.random.randint(key, (24,), 0, env.num_actions)
            new, ts = step(carry, actions)
            return new, (new, ts)

        keys = jax.random.split(jax.random.PRNGKey(1), env.max_steps + 40)
        return lax.scan(body, states, keys)[1]

    ours = fast_jit(lambda: run(learner._step_envs))()
    reference = fast_jit(lambda: run(jax.vmap(env.step)))()
    dones = np.asarray(ours[1].terminated | ours[1].truncated)
    assert dones.sum(1).max() > 16 and dones.sum() >= 24  # several chunks at once; every env
    for a, b in zip(leaves(ours), leaves(reference), strict=True):
        np.testing.assert_array_equal(a, b)


def test_sentence_encoders_skip_the_pad_tail():
    """The policy's sentence features run the GRU over the table's longest sentence only,
    with the same bits as over every padded token."""
    learner = make_learner(TINY)
    lengths = np.sum(np.asarray(learner.table) != 0, axis=1)
    assert learner.words == lengths.max() < learner.table.shape[1]
    params = learner.init(jax.random.PRNGKey(0)).params
    full = jax.jit(learner.replace(words=learner.table.shape[1])._lang_table)(params)
    np.testing.assert_array_equal(jax.jit(learner._lang_table)(params), full)


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


def test_novelty_bonus_pays_first_visits_per_episode():
    """The bonus is the reward difference against the same rollout without it (same params
    and keys, so the same actions), and equals a host replay of episodic first visits."""
    base = dataclasses.replace(TINY, env_kwargs=SHORT)
    plain, bonus = make_learner(base), make_learner(dataclasses.replace(base, novelty_bonus=0.5))
    runner = plain.init(jax.random.PRNGKey(3))
    tr0, carry0 = rollout(plain, runner)
    tr1, carry1 = rollout(bonus, bonus.init(jax.random.PRNGKey(3)))
    np.testing.assert_array_equal(tr0.action, tr1.action)
    got = tr1.reward - tr0.reward

    def visit(state, t, e):
        x, y = state.agent_pos[t, e] if t is not None else state.agent_pos[e]
        carrying = state.carrying[t, e, 0] if t is not None else state.carrying[e, 0]
        return int(x), int(y), bool(carrying != 1)

    start = jax.device_get(runner.env.state)
    expected = np.zeros_like(got)
    for e in range(got.shape[1]):
        seen = {visit(start, None, e)}
        for t in range(got.shape[0]):
            cell = visit(carry1.state, t, e)
            if tr1.done[t, e]:
                seen = {cell}  # the returned state starts the next episode
                continue
            expected[t, e] = 0.5 * (cell not in seen)
            seen.add(cell)
    np.testing.assert_allclose(got, expected, atol=1e-6)
    assert 0 < (expected > 0).mean() < 1  # both first visits and revisits happen
    assert tr1.done.any()  # and episodes restart within the rollout


def test_terminal_step_on_the_time_limit_is_not_bootstrapped():
    """LavaGap with max_steps=1: every step truncates; stepping into lava also terminates."""
    config = dataclasses.replace(
        TINY, env_id="MiniGrid-LavaGapS5-v0", env_kwargs=(("max_steps", 1),), num_envs=16
    )
    learner = make_learner(config)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(1))
    tr, carries = rollout(learner, runner, steps=8)

    @fast_jit
    def values_of_final(runner, actions):
        auto = AutoReset(learner.env)
        lang = learner._lang_table(runner.params)

        def step(state, action):
            state, ts = jax.vmap(auto.step)(state, action)
            final = ts.info["final_observation"]
            sentence = jnp.zeros(action.shape, jnp.int32)
            _, v, _ = learner._policy(
                runner.params, lang, final["image"], final["direction"], sentence
            )
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


# ------------------------------------------------------------------------ 7 + 8. runner
@pytest.fixture(scope="module")
def uninterrupted():
    """The reference run; it also builds the runner's programs that later calls reuse.

    ``run`` keeps its jitted programs per configuration, so jitting them with ``FAST``
    options here makes every later ``run(TINY, ...)`` of this module use them too.
    """
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(jax, "jit", functools.partial(jax.jit, compiler_options=FAST))
        # Two chunks, one trace: a retrace (dtype, weak type, sharding drift) raises here.
        patch.setattr(Learner, "chunk", chex.assert_max_traces(Learner.chunk, n=1))
        try:
            return run(TINY, seeds=SEEDS, progress=False)
        finally:
            chex.clear_trace_counter()


def read_jsonl(path):
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def test_runner_compiles_once(uninterrupted):
    """The chunk is traced once for both chunks (see the fixture) and a second call of
    ``run`` with the same configuration reuses the compiled programs."""
    again = run(TINY, seeds=SEEDS, progress=False)
    programs = runner_mod._programs(TINY, None, False)
    assert programs.init._cache_size() == 1 and programs.chunk._cache_size() == 1
    assert again["records"] == uninterrupted["records"]
    assert again["wall_s"] < uninterrupted["wall_s"]


def test_run_result(uninterrupted):
    r = uninterrupted
    assert r["complete"]
    np.testing.assert_array_equal(r["steps"], [2 * TINY.batch_size, 4 * TINY.batch_size])
    for k in ("violation_rate", "mean_reward", "success_rate"):
        assert r["eval"][k].shape == (2, TINY.num_chunks)
    assert len(r["records"]) == 2 * TINY.num_chunks
    assert all(np.all(np.isfinite(x)) for x in leaves(r["params"]))


def test_checkpoint_resume_is_bit_identical(tmp_path, uninterrupted):
    first = run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, max_chunks=1)
    assert not first["complete"]
    records = read_jsonl(tmp_path / "metrics.jsonl")
    assert sorted((r["seed"], r["chunk"]) for r in records) == [(0, 0), (1, 0)]
    assert (tmp_path / "checkpoints" / "1").is_dir()

    second = run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False)
    assert second["complete"]
    records = read_jsonl(tmp_path / "metrics.jsonl")
    assert sorted((r["seed"], r["chunk"]) for r in records) == [
        (s, c) for s in SEEDS for c in (0, 1)
    ]
    assert records == second["records"]
    for a, b in zip(leaves(second["params"]), leaves(uninterrupted["params"]), strict=True):
        np.testing.assert_array_equal(a, b)
    for a, b in zip(leaves(second["runner"]), leaves(uninterrupted["runner"]), strict=True):
        np.testing.assert_array_equal(a, b)
    for k, v in uninterrupted["eval"].items():
        np.testing.assert_array_equal(second["eval"][k], v)
    np.testing.assert_array_equal(second["train_violations"], uninterrupted["train_violations"])
    cum = [r["train/cum_violations"] for r in records if r["seed"] == 0]
    assert cum == sorted(cum)
    # One compilation served every call, the resumed (restored) state included.
    programs = runner_mod._programs(TINY, None, False)
    assert programs.init._cache_size() == 1 and programs.chunk._cache_size() == 1

    # Resuming with other seeds or another configuration is refused ...
    with pytest.raises(ValueError, match="seeds"):
        run(TINY, seeds=(0, 2), out_dir=tmp_path, progress=False)
    with pytest.raises(ValueError, match="lr"):
        run(dataclasses.replace(TINY, lr=5e-4), seeds=SEEDS, out_dir=tmp_path, progress=False)
    # ... and resume=False really starts over (old checkpoints are not resumed later).
    fresh = run(TINY, seeds=(3, 4), out_dir=tmp_path, progress=False, resume=False, max_chunks=1)
    assert not fresh["complete"]
    done = run(TINY, seeds=(3, 4), out_dir=tmp_path, progress=False)
    assert done["complete"]
    assert {r["seed"] for r in read_jsonl(tmp_path / "metrics.jsonl")} == {3, 4}
    assert len(read_jsonl(tmp_path / "metrics.jsonl")) == 4


def test_non_finite_chunk_raises_and_keeps_last_checkpoint(tmp_path, monkeypatch, uninterrupted):
    run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False, max_chunks=1)
    restore = runner_mod._restore

    def poisoned(*args, **kwargs):
        r = restore(*args, **kwargs)
        return r.replace(params=jax.tree.map(lambda x: x * jnp.nan, r.params))

    monkeypatch.setattr(runner_mod, "_restore", poisoned)
    with pytest.raises(NonFiniteError, match=r"within updates 3-4 \(seeds \[0, 1\]\)"):
        run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False)
    monkeypatch.setattr(runner_mod, "_restore", restore)

    # The last good checkpoint is untouched and loadable: resuming from it finishes the run
    # exactly as the uninterrupted one.
    manager = runner_mod._checkpoint_manager(tmp_path / "checkpoints")
    try:
        assert manager.all_steps() == [1]
    finally:
        manager.close()
    resumed = run(TINY, seeds=SEEDS, out_dir=tmp_path, progress=False)
    for a, b in zip(leaves(resumed["params"]), leaves(uninterrupted["params"]), strict=True):
        np.testing.assert_array_equal(a, b)


# -------------------------------------------------------------------- 10. evaluation
@pytest.fixture(scope="module")
def two_rooms():
    return jaxgrid.make("TwoRooms-v0")


class StateInObs:
    """An env whose observation also carries the state, for privileged policies."""

    def __init__(self, env):
        self.env, self.max_steps = env, env.max_steps

    def reset(self, key):
        state, ts = self.env.reset(key)
        return state, ts.replace(observation={**ts.observation, "state": state})

    def step(self, state, action):
        state, ts = self.env.step(state, action)
        return state, ts.replace(observation={**ts.observation, "state": state})


ORACLE, NOISY_ORACLE, DONE = 0, 1, 2


@pytest.fixture(scope="module")
def play(two_rooms):
    """``play(key, policy)``: 8 TwoRooms episodes; one program for the three policies."""
    env = StateInObs(two_rooms)

    def act(policy, obs, key):
        oracle = jax.vmap(oracle_action)(obs["state"])
        k1, k2 = jax.random.split(key)
        shape = oracle.shape
        noisy = jnp.where(
            jax.random.uniform(k1, shape) < 0.3, jax.random.randint(k2, shape, 0, 3), oracle
        )
        done = jnp.full(shape, 6, jnp.int32)
        return jnp.select([policy == ORACLE, policy == NOISY_ORACLE], [oracle, noisy], done)

    @fast_jit
    def go(key, policy):
        return play_episodes(env, functools.partial(act, policy), key, 8)

    return lambda key, policy: jax.device_get(go(jax.random.PRNGKey(key), policy))


def test_play_episodes_is_deterministic_for_a_key(play):
    a, b, c = play(5, NOISY_ORACLE), play(5, NOISY_ORACLE), play(6, NOISY_ORACLE)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    assert not np.array_equal(a["length"], c["length"])
    assert np.all(a["violated"] == (a["violations"] > 0))
    assert np.all((a["length"] >= 1) & (a["length"] <= 100))


def test_oracle_succeeds_without_violations(play, two_rooms):
    ep = play(11, ORACLE)
    rates = jax.device_get(summarise(ep))
    assert rates["success_rate"] == 1.0 and rates["violation_rate"] == 0.0
    assert np.all(ep["violations"] == 0)
    # MiniGrid's reward, counted once per episode and only until the episode ends.
    np.testing.assert_allclose(
        ep["reward"], 1 - 0.9 * ep["length"] / two_rooms.max_steps, rtol=1e-6
    )


def test_done_action_never_succeeds(play, two_rooms):
    ep = play(2, DONE)
    assert not ep["success"].any() and not ep["violated"].any()
    np.testing.assert_array_equal(ep["length"], two_rooms.max_steps)
    np.testing.assert_array_equal(ep["reward"], 0.0)


# ---------------------------------------------------------------- 9. multi-device run
@pytest.mark.slow
def test_multi_device_run_matches_single_device(multi_device_process, uninterrupted):
    proc, out = multi_device_process
    try:
        log, _ = proc.communicate(timeout=300)
    except subprocess.TimeoutExpired:
        proc.kill()
        pytest.fail("the 4-device run did not finish in 300 s")
    assert proc.returncode == 0, log[-4000:]
    result = json.loads((out / "result.json").read_text())
    assert "divisible by the number of devices (4)" in result["bad"]["error"]
    # The env batch really is split over the 4 devices (seed axis, then envs).
    assert result["env_devices"] == 4
    assert result["env_shard_shape"][1] * 4 == result["env_shape"][1] == TINY.num_envs
    with np.load(out / "params.npz") as f:
        sharded = [f[f"arr_{i}"] for i in range(len(f.files))]
    single = leaves(uninterrupted["params"])
    assert len(sharded) == len(single)
    for a, b in zip(sharded, single, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)
    for k, v in uninterrupted["eval"].items():
        np.testing.assert_allclose(result["eval"][k], v, atol=1e-5, err_msg=k)
    np.testing.assert_array_equal(result["train_violations"], uninterrupted["train_violations"])


@pytest.mark.parametrize("shape", [(4, 5, 5, 8), (2, 7, 6, 3)])
def test_patch_conv_equals_flax_conv(shape):
    import flax.linen as nn

    from agents.networks import PatchConv

    x = jax.random.normal(jax.random.PRNGKey(0), shape)
    params = PatchConv(16).init(jax.random.PRNGKey(1), x)
    ours = PatchConv(16).apply(params, x)
    ref = nn.Conv(16, (3, 3), padding="VALID").apply(params, x)
    np.testing.assert_allclose(ours, ref, rtol=1e-5, atol=1e-5)
