"""``agents.train``: ``jit(vmap(make_train))`` over seeds, the Lagrange multiplier, the MLP
view encoder, the sentence encoders on the table's real tokens only, and schedules that end
on the last update actually run."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from helpers.agents_cases import FAST, SEEDS, TINY, fast_jit, keys_of, leaves

from agents.config import PPOConfig
from agents.train import make_learner, make_train

LAGRANGIAN = dataclasses.replace(
    TINY, reward_mode="lagrangian", checker_threshold=1e-6, cost_limit=0.25, lagrangian_lr=0.1
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
    # episode is the rollout's steps over its episodes, far above cost_limit.
    np.testing.assert_allclose(cost, 1.0)
    episodes = t["episodes"].reshape(2, -1)
    np.testing.assert_allclose(
        episode_cost, LAGRANGIAN.batch_size / np.maximum(episodes, 1), rtol=1e-6
    )
    prev = np.concatenate([np.full((2, 1), LAGRANGIAN.lagrangian_init), lam[:, :-1]], axis=1)
    step = LAGRANGIAN.lagrangian_lr * (episode_cost - LAGRANGIAN.cost_limit)
    expected = np.maximum(0.0, prev + step)
    np.testing.assert_allclose(lam, expected, rtol=1e-6)
    assert np.all(np.diff(lam, axis=1) > 0) and np.all(lam[:, 0] > 0)
    assert np.all(t["alarms"] == LAGRANGIAN.batch_size)
    assert np.all(np.asarray(out["runner"].lagrange) == lam[:, -1])


def test_env_cost_is_the_monitors_whatever_the_learners_cost(lagrangian_train):
    """The learner's cost here is the checker's alarm on every step (cost rate 1); the env's
    cost stays the monitor's: on TwoRooms, whose constraints all forbid, one per violation."""
    t = lagrangian_train[0]["train"]
    assert t["env_cost"].shape == t["violations"].shape == (2, *t["loss"].shape[1:])
    np.testing.assert_array_equal(t["env_cost"], t["violations"])
    assert t["env_cost"].sum() < t["cost_rate"].sum() * LAGRANGIAN.batch_size


@pytest.mark.slow  # penalty_start is an ablation flag; the multiplier is tested above
def test_lagrange_multiplier_waits_for_penalty_start(tiny_checker):
    """Before ``penalty_start`` the multiplier stays at ``lagrangian_init``; then it moves."""
    # penalty=0: the multiplier follows the schedule, not the shaping penalty's size.
    config = dataclasses.replace(LAGRANGIAN, penalty_start=0.5, penalty=0.0)
    learner = make_learner(config, tiny_checker)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))
    update = fast_jit(learner.update)
    lams = []
    for _ in range(config.num_updates):
        runner, m = update(runner)
        lams.append(float(m["lagrange"]))
    half = config.num_updates // 2
    assert all(lam == config.lagrangian_init for lam in lams[:half])
    assert lams[-1] > config.lagrangian_init


def test_mlp_view_encoder_option():
    """``conv_channels=()`` builds the policy without the convolution and still trains."""
    config = dataclasses.replace(TINY, conv_channels=[])
    assert config.conv_channels == () and hash(config) != hash(TINY)
    learner = make_learner(config)
    assert learner.network.conv_channels == ()
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))
    assert not any("convs" in jax.tree_util.keystr(p) for p, _ in
                   jax.tree_util.tree_leaves_with_path(runner.params))  # fmt: skip
    runner, metrics = fast_jit(learner.update)(runner)
    assert np.isfinite(float(metrics["loss"])) and int(runner.update) == 1


def test_cell_dim_sets_the_width_the_sentence_modulates():
    """``cell_dim`` is the width of every view cell's features and of the sentence's FiLM
    over them; the default is the network's own."""
    assert make_learner(TINY).network.cell_dim == TINY.cell_dim == 8
    learner = make_learner(dataclasses.replace(TINY, cell_dim=16))
    params = jax.eval_shape(learner.init, jax.random.PRNGKey(0)).params["params"]
    assert params["cells"]["kernel"].shape[-1] == 16
    assert params["lang_proj"]["kernel"].shape[-1] == learner.network.lang_dim == 2 * 16 + 2 * 64


def test_sentence_encoders_skip_the_pad_tail():
    """The policy's sentence features run the GRU over the table's longest sentence only,
    with the same bits as over every padded token."""
    learner = make_learner(TINY)
    lengths = np.sum(np.asarray(learner.table) != 0, axis=1)
    assert learner.words == lengths.max() < learner.table.shape[1]
    params = fast_jit(learner.init)(jax.random.PRNGKey(0)).params
    full = fast_jit(learner.replace(words=learner.table.shape[1]).lang_table)(params)
    np.testing.assert_array_equal(fast_jit(learner.lang_table)(params), full)


@pytest.mark.slow  # two more training compiles (about 20 s)
def test_training_does_not_depend_on_the_evaluation_schedule():
    """Evaluation plays on its own fixed key: the same run evaluated after every update or
    once at the end trains bit-identical agents (``eval_every`` only sets the curves)."""
    runners = []
    for every in (1, 4):
        config = dataclasses.replace(TINY, eval_every=every)
        assert config.num_updates == TINY.num_updates == 4
        out = fast_jit(make_train(config))(jax.random.PRNGKey(3))
        assert out["eval"]["success_rate"].shape == (4 // every,)
        runners.append(jax.device_get(out["runner"]))
    for a, b in zip(leaves(runners[0]), leaves(runners[1]), strict=True):
        np.testing.assert_array_equal(a, b)


# 183 updates' worth of steps and eval_every 10: the run is 18 chunks, 180 updates.
ANNEALED = PPOConfig(
    num_envs=8, num_steps=8, total_timesteps=183 * 64 + 17, update_epochs=2, num_minibatches=2,
    eval_every=10, novelty_bonus=0.3, penalty=0.7, penalty_start=0.9, penalty_warmup=0.1,
    film_codes=False, alarm_forward=False,
)  # fmt: skip
# What a training run compiles with (the suite's default is cheaper, see tests/conftest.py).
OPTIMISED = {"xla_backend_optimization_level": 3}


def optimizer_steps(learner, steps: int, compiler_options=FAST):
    """The change of one parameter at each of ``steps`` steps of ``learner.optimizer``, driven
    with the same small gradient every step, and the optimizer's final state.

    Adam's direction is then the same at every step, so each change is the scheduled
    learning rate times one negative constant.
    """
    params = {"w": np.zeros(3, np.float32)}
    grads = {"w": np.full(3, 0.01, np.float32)}  # global norm far below max_grad_norm

    def drive(params):
        def step(carry, _):
            params, state = carry
            updates, state = learner.optimizer.update(grads, state, params)
            return (optax.apply_updates(params, updates), state), updates["w"][0]

        init = (params, learner.optimizer.init(params))
        (_, state), sizes = jax.lax.scan(step, init, None, steps)
        return sizes, state

    return jax.device_get(jax.jit(drive, compiler_options=compiler_options)(params))


def test_every_schedule_ends_on_the_last_update_run():
    """The penalty ramp, the novelty anneal and the learning rate all span the updates
    actually run (whole chunks), not ``total_timesteps // batch_size``.

    The learning rate is read off the real optimizer (``learner.optimizer``, see
    :func:`optimizer_steps`). ``Learner.update`` takes ``update_epochs * num_minibatches``
    optimizer steps (:func:`test_learner_takes_one_optimizer_step_per_minibatch`), so
    optimizer step ``k`` belongs to update ``k // (update_epochs * num_minibatches)``.
    """
    c = ANNEALED
    assert c.total_timesteps // c.batch_size == 183
    assert c.num_updates == 180 == c.num_chunks * c.eval_every
    learner = make_learner(c)
    last = c.num_updates - 1
    # Novelty: linear to 0; the last update pays 1/num_updates of the bonus. (float32's
    # 1 - 179/180 cancels: a few 1e-6 of relative error.)
    novelty = fast_jit(learner.novelty_at)
    assert float(novelty(jnp.int32(0))) == np.float32(c.novelty_bonus)
    np.testing.assert_allclose(novelty(jnp.int32(last)), c.novelty_bonus / c.num_updates,
                               rtol=1e-5)  # fmt: skip
    # Penalty: off for the first 90% of the updates, a ramp over the last 10% that reaches
    # the full penalty on the last update, not after it.
    ramp = np.asarray(fast_jit(jax.vmap(learner.penalty_at))(jnp.arange(c.num_updates)))
    start = int(c.penalty_start * c.num_updates)
    assert np.all(ramp[:start] == 0.0) and np.all(np.diff(ramp[start:]) > 0)
    assert ramp[last] == np.float32(c.penalty) and ramp[last - 1] < np.float32(c.penalty)
    # Learning rate: linear from lr, 1/num_updates of it on the last update's last step.
    per_update = c.update_epochs * c.num_minibatches
    steps = c.num_updates * per_update
    sizes, state = optimizer_steps(learner, steps)
    multiplier = sizes / sizes[0]
    expected = 1.0 - (np.arange(steps) // per_update) / c.num_updates
    # Neighbouring updates' multipliers differ by 1/180 of the first, at least 0.5% of
    # either; float32's 1 - 179/180 and Adam's rounding stay near 1e-5.
    np.testing.assert_allclose(multiplier, expected, rtol=1e-4, atol=0)
    assert sizes[-1] < 0
    counts = optax.tree_utils.tree_get_all_with_path(state, "count")
    assert counts and all(int(n) == steps for _, n in counts)


def test_novelty_anneal_ends_the_bonus_early():
    """``novelty_anneal`` f: the bonus falls linearly to 0 over the first f of the updates and
    stays 0 after; f = 1 is the whole run, the same values as before the setting existed."""
    c = dataclasses.replace(ANNEALED, novelty_anneal=0.25)
    novelty = fast_jit(jax.vmap(make_learner(c).novelty_at))
    values = np.asarray(novelty(jnp.arange(c.num_updates, dtype=jnp.int32)))
    end = int(0.25 * c.num_updates)  # 45 of 180
    assert values[0] == np.float32(c.novelty_bonus)
    assert np.all(np.diff(values[: end + 1]) < 0) and np.all(values[end:] == 0.0)
    np.testing.assert_allclose(values[end - 1], c.novelty_bonus / end, rtol=1e-5)
    c = ANNEALED
    whole = fast_jit(jax.vmap(make_learner(c).novelty_at))
    before = fast_jit(jax.vmap(lambda u: c.novelty_bonus * (1.0 - u / c.num_updates)))
    u = jnp.arange(c.num_updates, dtype=jnp.int32)
    np.testing.assert_array_equal(whole(u), before(u).astype(np.float32))
    for bad in (0.0, 1.5, -0.1):
        with pytest.raises(ValueError, match="novelty_anneal"):
            dataclasses.replace(ANNEALED, novelty_anneal=bad)


def test_penalty_gate_scales_the_penalty_by_the_last_updates_success():
    """``penalty_gate``: the ramp's penalty times min(1, success / gate), the success being
    the fraction of the last update's finished training episodes that reached the goal."""
    c = dataclasses.replace(TINY, reward_mode="shaped", penalty=0.8, penalty_gate=0.5,
                            num_envs=16, num_steps=104, total_timesteps=16 * 104 * 2)  # fmt: skip
    learner = make_learner(c)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))
    assert float(runner.success) == 0.0 and float(learner.penalty_of(runner)) == 0.0
    for success, scale in ((0.25, 0.5), (0.5, 1.0), (0.9, 1.0)):
        gated = learner.penalty_of(runner.replace(success=jnp.float32(success)))
        np.testing.assert_allclose(gated, 0.8 * scale, rtol=1e-6)
    ungated = make_learner(dataclasses.replace(c, penalty_gate=0.0))
    assert float(ungated.penalty_of(runner)) == np.float32(0.8)
    runner, metrics = fast_jit(learner.update)(runner)
    episodes, successes = int(metrics["episodes"]), int(metrics["successes"])
    assert episodes >= c.num_envs  # every episode ends within 100 steps
    np.testing.assert_allclose(runner.success, successes / episodes, rtol=1e-6)
    with pytest.raises(ValueError, match="penalty_gate"):
        dataclasses.replace(c, penalty_gate=1.5)


def test_anneals_end_at_zero_after_the_last_update():
    """After the last update (update ``num_updates``, optimizer step ``num_updates *
    update_epochs * num_minibatches``) the novelty bonus and the learning rate are 0 up to
    float32 rounding, as a training run compiles them (``1 - update / num_updates`` becomes a
    multiplication by ``1 / num_updates``: about -7e-9 of the bonus, +2e-11 of the rate).
    No update uses these values; the last update's are checked exactly above."""
    c = ANNEALED
    learner = make_learner(c)
    novelty = jax.jit(learner.novelty_at, compiler_options=OPTIMISED)
    steps = c.num_updates * c.update_epochs * c.num_minibatches
    sizes, _ = optimizer_steps(learner, steps + 1, compiler_options=OPTIMISED)
    assert sizes[steps - 1] < 0
    assert abs(float(novelty(jnp.int32(c.num_updates)))) <= 1e-6 * c.novelty_bonus
    assert abs(sizes[steps]) <= 1e-6 * abs(sizes[0])


def test_learner_takes_one_optimizer_step_per_minibatch(lagrangian_train):
    """``num_updates`` updates take ``num_updates * update_epochs * num_minibatches``
    optimizer steps: the count the learning-rate schedule is written against."""
    out, _ = lagrangian_train
    c = LAGRANGIAN
    counts = optax.tree_utils.tree_get_all_with_path(out["runner"].opt_state, "count")
    assert counts
    for _, n in counts:
        np.testing.assert_array_equal(n, c.num_updates * c.update_epochs * c.num_minibatches)
