"""``agents.losses``: GAE against a numpy loop, the minibatch shuffle (a permutation set by its
key, spreading every item evenly over minibatches), the PID Lagrangian's multiplier
answering a step of the cost, FOCOPS's update bounded in KL, and CPO's step inside its trust
region, with its recovery step where the policy is infeasible."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.agents_cases import fast_jit

from agents.config import PPOConfig
from agents.losses import PIDState, cpo_step, gae, pid_update, ppo_loss, shuffle


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


def test_gae_matches_numpy():
    rng = np.random.default_rng(0)
    values = rng.normal(size=(6, 3)).astype(np.float32)
    rewards = rng.normal(size=(6, 3)).astype(np.float32)
    dones = np.zeros((6, 3), bool)
    dones[2, 0] = dones[5, 1] = dones[0, 2] = dones[3, 2] = True
    last = rng.normal(size=3).astype(np.float32)
    adv, target = fast_jit(gae, static_argnums=(4, 5))(values, rewards, dones, last, 0.9, 0.8)
    ref_adv, ref_target = gae_reference(values, rewards, dones.astype(np.float32), last, 0.9, 0.8)
    np.testing.assert_allclose(adv, ref_adv, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(target, ref_target, rtol=1e-5, atol=1e-6)
    # Hand-checked entry: env 0 ends at t=2, so its advantage there is r - V (no future).
    np.testing.assert_allclose(adv[2, 0], rewards[2, 0] - values[2, 0], rtol=1e-6)


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


def test_pid_multiplier_answers_a_cost_step():
    """A cost that steps from 0 to 2 (limit 0.5) for 4 updates, back to 0 for 14, then up
    again: the multiplier jumps at once (proportional and derivative terms), then builds up
    (integral), falls to 0 as soon as the cost is back under the limit, and answers the
    second step exactly as the first: the integral, clipped at 0, did not wind up below it."""
    kp, ki, kd, limit = 1.0, 0.05, 0.5, 0.5
    costs = [0.0] * 3 + [2.0] * 4 + [0.0] * 14 + [2.0] * 4
    step = fast_jit(lambda s, c: pid_update(s, c, limit, kp, ki, kd))
    state = PIDState(np.float32(0.0), np.float32(0.0))
    lams, integrals = [], []
    for cost in costs:
        lam, state = step(state, np.float32(cost))
        lams.append(float(lam))
        integrals.append(float(state.integral))
    lams, integrals = np.array(lams), np.array(integrals)
    assert np.all(lams[:3] == 0) and np.all(integrals[:3] == 0)  # under the limit: 0, no windup
    # The step: the proportional and derivative terms at once, then the integral's build-up.
    np.testing.assert_allclose(lams[3], kp * 1.5 + ki * 1.5 + kd * 2.0, rtol=1e-6)
    np.testing.assert_allclose(np.diff(lams[4:7]), ki * 1.5, rtol=1e-5)
    np.testing.assert_allclose(integrals[3:7], 1.5 * np.arange(1, 5), rtol=1e-6)
    # Back under the limit: the proportional term takes the multiplier to 0 at once while the
    # integral drains, clipped at 0 instead of winding up below it.
    assert lams[6] > 1 and np.all(lams[7:21] == 0)
    np.testing.assert_allclose(integrals[7:21], np.maximum(0, 6 - 0.5 * np.arange(1, 15)))
    assert np.all(integrals[18:21] == 0) and np.all(integrals >= 0)
    # The second step is answered as the first, bit for bit.
    np.testing.assert_array_equal(lams[21:], lams[3:7])


# A tabular policy: sample i is in state ``image[i]``, whose logits are row ``image[i]`` of
# the parameters; every (state, action) pair once, from a uniform old policy.
STATES, ACTIONS = 4, 3


def tabular(params, image, direction, sentence):
    zeros = jnp.zeros(image.shape)
    return params[image], zeros, zeros


def tabular_batch(advantage, cost_advantage) -> dict:
    n = STATES * ACTIONS
    zeros = jnp.zeros(n)
    return {
        "image": jnp.repeat(jnp.arange(STATES), ACTIONS), "direction": zeros.astype(jnp.int32),
        "sentence": zeros.astype(jnp.int32), "action": jnp.tile(jnp.arange(ACTIONS), STATES),
        "log_prob": jnp.full(n, -np.log(ACTIONS), jnp.float32), "value": zeros,
        "target": zeros, "cost_value": zeros, "cost_target": zeros,
        "advantage": jnp.tile(jnp.asarray(advantage, jnp.float32), STATES),
        "cost_advantage": jnp.tile(jnp.asarray(cost_advantage, jnp.float32), STATES),
        "logits": jnp.zeros((n, ACTIONS)),
    }  # fmt: skip


def kl_to_uniform(params):
    log_probs = jax.nn.log_softmax(params)
    return jnp.sum(jnp.exp(log_probs) * (log_probs + np.log(ACTIONS)), axis=-1)


def test_focops_update_stays_within_its_kl_bound():
    """A state whose KL to the old policy exceeds ``focops_max_kl`` gives no gradient, so
    that descending FOCOPS's loss stops each state near the bound (one step's overshoot),
    where without the bound it goes on to the reweighted policy, ten times as far."""
    batch = tabular_batch([3.0, -1.0, -2.0], [0.0, 0.0, 0.0])
    focops = dataclasses.replace(PPOConfig(), reward_mode="focops", ent_coef=0.0)
    grad = jax.grad(lambda p, c: ppo_loss(tabular, p, batch, 0.0, c)[0])
    moved = jnp.zeros((STATES, ACTIONS)).at[0].set(jnp.array([2.0, 0.0, 0.0]))
    assert kl_to_uniform(moved)[0] > focops.focops_max_kl
    g = grad(moved, focops)
    assert np.all(g[0] == 0) and np.all(np.abs(g[1:]) > 0)
    kls = {}
    for bound in (focops.focops_max_kl, 1e6):
        config = dataclasses.replace(focops, focops_max_kl=bound)

        @fast_jit
        def descend(params, config=config):
            step = lambda p, _: (p - grad(p, config), None)  # noqa: E731
            return jax.lax.scan(step, params, None, 400)[0]

        kls[bound] = np.asarray(kl_to_uniform(descend(jnp.zeros((STATES, ACTIONS)))))
    bounded, free = kls[focops.focops_max_kl], kls[1e6]
    assert np.all(bounded > focops.focops_max_kl * 0.9)  # it did move up to the bound
    assert np.all(bounded < focops.focops_max_kl * 1.25) and np.all(free > 10 * bounded)


CPO = dataclasses.replace(PPOConfig(), reward_mode="cpo", cpo_damping=1e-3)


@pytest.fixture(scope="module")
def cpo_steps():
    """CPO steps of the tabular policy from uniform, where action 0 earns the most reward
    and is the only costly one, at four distances of the cost from its limit."""
    batch = tabular_batch([3.0, -1.0, -2.0], [1.0, 0.0, 0.0])
    state = batch["image"]
    logits_of = lambda p: p[state]  # noqa: E731
    step = fast_jit(lambda excess: cpo_step(logits_of, jnp.zeros((STATES, ACTIONS)), batch,
                                            excess, CPO))  # fmt: skip
    out = {}
    for excess in (-1.0, -0.01, 0.01, 1.0):
        params, stats = jax.device_get(step(jnp.float32(excess)))
        probs = np.asarray(jax.nn.softmax(params[0]))
        # the surrogates' change: mean ratio x advantage (normalised) and x cost advantage
        ratio = probs * ACTIONS
        adv = np.array([3.0, -1.0, -2.0])
        adv = (adv - adv.mean()) / adv.std()
        gain, rise = (ratio * adv).mean(), (ratio * np.array([2, -1, -1]) / 3).mean()
        kl = np.mean(np.sum((np.log(1 / ACTIONS) - jax.nn.log_softmax(params)) / ACTIONS, -1))
        out[excess] = (params, stats, probs, gain, rise, float(kl))  # KL(old || new)
    return out


def test_cpo_steps_stay_inside_the_trust_region(cpo_steps):
    """Whatever the case, the step's measured mean KL is within ``cpo_max_kl`` (and uses
    most of it); where the cost has slack, it rises by no more than the slack."""
    cases = {excess: int(v[1]["cpo_case"]) for excess, v in cpo_steps.items()}
    assert cases == {-1.0: 3, -0.01: 2, 0.01: 1, 1.0: 0}  # every case of the dual
    for excess, (_, stats, _, _, rise, kl) in cpo_steps.items():
        assert stats["cpo_step"] > 0
        np.testing.assert_allclose(stats["cpo_kl"], kl, rtol=1e-4)
        assert 0.6 * CPO.cpo_max_kl < kl <= CPO.cpo_max_kl, excess
        assert rise <= max(-excess, 0.0) + 1e-6, excess
    # Far from the limit it is the trust region's reward step; at a slack of 0.01 the cost
    # binds: less of the costly action, still more reward.
    far, near = cpo_steps[-1.0], cpo_steps[-0.01]
    assert far[3] > near[3] > 0 and far[2][0] > near[2][0]
    assert 0.5 * 0.01 < near[4] <= 0.01 < far[4]  # the cost takes up most of its slack


def test_cpo_recovers_an_infeasible_policy_by_lowering_its_cost_alone(cpo_steps):
    """Over the limit by more than the trust region can undo (case 0), the step is the pure
    decrease of the cost: the costly action loses, the others gain alike whatever their
    rewards, and the reward surrogate falls with the cost's."""
    _, stats, probs, gain, rise, _ = cpo_steps[1.0]
    assert int(stats["cpo_case"]) == 0 and rise < 0 and gain < 0
    assert probs[0] < 1 / 3 and probs[1] == pytest.approx(probs[2], rel=1e-6)
    assert cpo_steps[0.01][2][1] > cpo_steps[0.01][2][2]  # near the limit, the reward counts
