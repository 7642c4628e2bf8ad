"""The constrained-RL baselines in the learner: each trains through the one rollout, loss and
update, and shows the behaviour that defines it on a tiny run: the PID Lagrangian's
multiplier follows its controller; Saute's policy observes the episode's remaining budget,
which each cost spends, and its reward is cut once the budget is overspent; FOCOPS's
multiplier moves by its gradient steps up to its cap, and its loss keeps the samples within
its KL bound; a CPO update moves the policy by its trust-region step alone; each traces with
a recurrent policy. A mode's own
state goes through checkpoints, and stays out of the other modes' (theirs hold what they
held before it existed)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.agents_cases import TINY, fast_jit, leaves

from agents import checkpoint
from agents.config import PPOConfig
from agents.losses import PIDState
from agents.runner import run
from agents.train import make_learner, make_train

# Threshold ~0: every step alarms, so the cost per episode is the rollout's steps over the
# episodes it finished, far above the limit; episodes of 5 steps end 8 or 16 times in the 8
# steps of an update, so the cost changes from one update to the next.
PID = dataclasses.replace(
    TINY, reward_mode="pid_lagrangian", checker_threshold=1e-6, cost_limit=0.25, pid_kp=0.5,
    pid_ki=0.1, pid_kd=0.2, env_kwargs=(("max_steps", 5),),
)  # fmt: skip


# Every step alarms (cost 1) against a limit of 4: the budget falls by a quarter per step
# (exactly, in floats), and the fifth step of an episode (6 steps) overspends it.
SAUTE = dataclasses.replace(
    TINY, reward_mode="saute", checker_threshold=1e-6, cost_limit=4.0, saute_penalty=0.5,
    env_kwargs=(("max_steps", 6),),
)  # fmt: skip


# The same huge cost: FOCOPS's multiplier climbs by lagrangian_lr x (cost - limit) and stops
# at focops_nu_max within the run.
FOCOPS = dataclasses.replace(
    PID, reward_mode="focops", lagrangian_lr=0.03, focops_nu_max=0.3, pid_kp=PPOConfig.pid_kp,
    pid_ki=PPOConfig.pid_ki, pid_kd=PPOConfig.pid_kd,
)  # fmt: skip


@pytest.fixture(scope="module")
def pid_run(tiny_checker):
    return jax.device_get(fast_jit(make_train(PID, tiny_checker))(jax.random.PRNGKey(0)))


def test_pid_lagrangian_multiplier_follows_its_controller(pid_run):
    """The multiplier of every update is the PID controller's on that update's cost per
    episode (no derivative at the first), and the runner keeps the controller's memory."""
    t = pid_run["train"]
    cost, lam = t["episode_cost"].ravel(), t["lagrange"].ravel()
    np.testing.assert_allclose(t["cost_rate"], 1.0)
    assert len(set(cost.tolist())) > 1  # the cost changes, so the derivative term acts
    integral, previous, expected = 0.0, cost[0], []
    for c in cost:
        error = c - PID.cost_limit
        integral = max(0.0, integral + error)
        rise = max(0.0, c - previous)
        expected.append(max(0.0, PID.pid_kp * error + PID.pid_ki * integral + PID.pid_kd * rise))
        previous = c
    np.testing.assert_allclose(lam, expected, rtol=1e-5)
    runner = pid_run["runner"]
    np.testing.assert_allclose(runner.pid.integral, integral, rtol=1e-5)
    assert runner.pid.cost == cost[-1] and runner.lagrange == lam[-1]


def test_a_modes_own_state_goes_through_checkpoints_and_only_there(tmp_path, tiny_checker):
    key = jax.random.PRNGKey(0)
    pid = make_learner(PID, tiny_checker)
    runner = fast_jit(pid.init)(key)
    runner = runner.replace(pid=PIDState(jnp.float32(1.5), jnp.float32(2.5)))
    manager = checkpoint.make_manager(tmp_path / "pid" / "checkpoints")
    checkpoint.save(manager, 1, runner, tmp_path / "pid", [])
    back = checkpoint.restore(manager, 1, jax.eval_shape(pid.init, key), None)
    assert (float(back.pid.integral), float(back.pid.cost)) == (1.5, 2.5)
    for a, b in zip(leaves(back), leaves(runner), strict=True):
        np.testing.assert_array_equal(a, b)
    # A mode without it saves no trace of it: the checkpoint older code wrote.
    lagrangian = make_learner(dataclasses.replace(PID, reward_mode="lagrangian"), tiny_checker)
    runner = fast_jit(lagrangian.init)(key)
    assert runner.pid is None
    manager = checkpoint.make_manager(tmp_path / "lagrangian" / "checkpoints")
    checkpoint.save(manager, 1, runner, tmp_path / "lagrangian", [])
    saved = manager.restore(1)
    assert "pid" not in saved and "budget" not in saved["env"]
    # Saute's budget lives in the env carry, and goes through checkpoints with it.
    saute = make_learner(dataclasses.replace(SAUTE, cost_source="monitor"))
    runner = fast_jit(saute.init)(key)
    runner = runner.replace(env=runner.env.replace(budget=runner.env.budget * 0.5))
    manager = checkpoint.make_manager(tmp_path / "saute" / "checkpoints")
    checkpoint.save(manager, 1, runner, tmp_path / "saute", [])
    back = checkpoint.restore(manager, 1, jax.eval_shape(saute.init, key), None)
    np.testing.assert_array_equal(back.env.budget, 0.5)


@pytest.mark.slow  # resume is tested in test_runner.py; a mode's state in checkpoints above
def test_a_baseline_runs_and_resumes_through_the_runner(tmp_path):
    """``agents.runner.run`` trains the PID Lagrangian (its controller in the runner state)
    over seeds, and a run stopped after a chunk resumes to the same agents, bit for bit."""
    config = dataclasses.replace(PID, cost_source="monitor")
    whole = run(config, seeds=(0, 1), progress=False)
    run(config, seeds=(0, 1), out_dir=tmp_path, progress=False, max_chunks=1)
    resumed = run(config, seeds=(0, 1), out_dir=tmp_path, progress=False)
    assert resumed["complete"] and whole["runner"].pid.cost.shape == (2,)
    for a, b in zip(leaves(whole["runner"]), leaves(resumed["runner"]), strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.fixture(scope="module")
def saute_run(tiny_checker):
    """A rollout from a fresh Saute learner, and a chunk of training from the same start."""
    learner = make_learner(SAUTE, tiny_checker)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))

    @fast_jit
    def go(runner):
        _, traj, _ = learner.rollout(runner, runner.key)
        return traj, learner.chunk(runner)

    return learner, runner, jax.device_get(go(runner))


def test_saute_observes_its_budget_which_costs_spend_and_cuts_the_reward(saute_run):
    learner, runner, (traj, _) = saute_run
    done = np.asarray(traj.done)
    budget, seen, cut = np.ones(done.shape[1], np.float32), [], []
    for t in range(done.shape[0]):  # 1 at an episode's start, a quarter less per step
        seen.append(budget)
        after = np.clip(budget - 0.25, -1, 1)
        cut.append(after < 0)
        budget = np.where(done[t], 1.0, after).astype(np.float32)
    np.testing.assert_array_equal(traj.budget, np.stack(seen))
    cut = np.stack(cut)
    inside = ~done  # truncated steps add the final observation's value
    assert (cut & inside).any() and (~cut & inside).any()
    np.testing.assert_array_equal(traj.reward[cut & inside], -SAUTE.saute_penalty)
    assert np.all(traj.reward[~cut & inside] >= 0)  # the env reward, uncut
    # The policy reads the budget: an overspent one changes its action probabilities.
    obs, env = runner.env.obs, runner.env
    policy = learner.policy(runner.params)
    logits = fast_jit(lambda budget: policy(obs["image"], obs["direction"], env.sentence,
                                            env.memory, budget)[0])  # fmt: skip
    full, spent = logits(env.budget), logits(-env.budget)
    assert np.all(np.asarray(env.budget) == 1) and not np.allclose(full, spent)


def test_saute_trains_and_evaluates_with_its_budget(saute_run):
    _, _, (_, (runner, metrics)) = saute_run
    assert int(runner.update) == SAUTE.eval_every
    assert np.all(np.isfinite(metrics["train"]["loss"]))
    np.testing.assert_allclose(metrics["train"]["cost_rate"], 1.0)
    assert 0 <= float(metrics["eval"]["success_rate"]) <= 1


def test_focops_multiplier_climbs_to_its_cap_and_its_loss_keeps_close_samples(tiny_checker):
    out = jax.device_get(fast_jit(make_train(FOCOPS, tiny_checker))(jax.random.PRNGKey(0)))
    t = out["train"]
    cost, nu = t["episode_cost"].ravel(), t["lagrange"].ravel()
    expected, previous = [], FOCOPS.lagrangian_init
    for c in cost:
        step = FOCOPS.lagrangian_lr * (c - FOCOPS.cost_limit)
        previous = min(FOCOPS.focops_nu_max, max(0.0, previous + step))
        expected.append(previous)
    np.testing.assert_allclose(nu, expected, rtol=1e-5)
    assert nu[0] < FOCOPS.focops_nu_max == nu[-1]
    kept = t["focops_kept"]
    assert np.all((kept > 0.5) & (kept <= 1)) and np.all(np.isfinite(t["loss"]))


@pytest.mark.parametrize("mode", ["pid_lagrangian", "saute", "focops", "cpo"])
def test_each_baseline_traces_with_a_recurrent_policy(mode):
    """The update of each traces (not compiled) with a memory policy, which replays whole
    sequences, on the monitor's cost."""
    config = dataclasses.replace(TINY, reward_mode=mode, cost_source="monitor", recurrent=True)
    learner = make_learner(config)
    runner = jax.eval_shape(learner.init, jax.random.PRNGKey(0))
    after, metrics = jax.eval_shape(learner.update, runner)
    assert jax.tree.structure(after) == jax.tree.structure(runner)
    assert metrics["loss"].shape == ()


def test_cpo_update_moves_the_policy_by_its_trust_region_step_alone():
    """The policy after a whole CPO update (the step, then the epochs that fit the value
    heads) is as far from the acting one as the step measured, within ``cpo_max_kl``: the
    value fitting moved the values, not the policy."""
    config = dataclasses.replace(TINY, reward_mode="cpo", cost_source="monitor")
    learner = make_learner(config)
    runner = fast_jit(learner.init)(jax.random.PRNGKey(0))

    @fast_jit
    def go(runner):
        batch = learner.collect(runner, jax.random.split(runner.key, 3)[1])[3]
        after, metrics = learner.update(runner)
        return batch, after, metrics, learner.forward(after.params, batch)[0]

    batch, after, metrics, logits = jax.device_get(go(runner))
    old, new = jax.nn.log_softmax(batch["logits"]), jax.nn.log_softmax(logits)
    kl = float(np.mean(np.sum(np.exp(old) * (old - new), axis=-1)))
    assert metrics["cpo_step"] > 0 and 0 < kl <= config.cpo_max_kl
    np.testing.assert_allclose(kl, metrics["cpo_kl"], rtol=1e-4)
    before, fitted = runner.params["params"], after.params["params"]
    for head in ("critic", "cost_critic"):
        assert not np.array_equal(before[head]["kernel"], fitted[head]["kernel"])
    assert np.isfinite(metrics["loss"]) and metrics["value_loss"] >= 0
