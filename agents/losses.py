"""PPO's pure learning pieces: GAE, the clipped loss, and the minibatch shuffle.

They take arrays and the network's apply function, never a learner object, so they can be
tested and reused on their own.
"""

from __future__ import annotations

from collections.abc import Callable

import flax.struct as struct
import jax
import jax.numpy as jnp
from jax import lax
from jax.flatten_util import ravel_pytree

from agents.config import PPOConfig
from agents.shield import blocked_mass, mask_logits


def gae(
    values: jax.Array,
    rewards: jax.Array,
    dones: jax.Array,
    last_value: jax.Array,
    gamma: float,
    gae_lambda: float,
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimates and value targets over a rollout.

    ``values``, ``rewards`` float32 (T, E); ``dones`` bool (T, E), True where step t ended
    its episode (terminated or truncated); ``last_value`` float32 (E,), the value of the
    observation after the last step. Returns ``(advantages, targets)``, both (T, E), with
    ``targets = advantages + values``. A done step does not bootstrap from the next step
    (which belongs to a new episode): a truncated step's reward must already include
    ``gamma * V(final observation)``, as the rollout adds it.
    """

    def step(carry, x):
        advantage, next_value = carry
        value, reward, done = x
        not_done = 1.0 - done.astype(jnp.float32)
        delta = reward + gamma * next_value * not_done - value
        advantage = delta + gamma * gae_lambda * not_done * advantage
        return (advantage, value), advantage

    init = (jnp.zeros_like(last_value), last_value)
    _, advantages = lax.scan(step, init, (values, rewards, dones), reverse=True)
    return advantages, advantages + values


Policy = Callable[..., tuple[jax.Array, jax.Array, jax.Array]]


def ppo_loss(
    policy: Policy,
    params,
    batch: dict[str, jax.Array],
    lagrange: jax.Array,
    config: PPOConfig,
    blocked_weight: jax.Array | float = 0.0,
    ent_coef: jax.Array | float | None = None,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """Clipped PPO loss of one minibatch, with the cost critic in the constrained modes.

    ``policy(params, image, direction, sentence) -> (logits (B, A), value (B,),
    cost_value (B,))``. ``batch`` holds (B, ...) arrays ``image``, ``direction``,
    ``sentence``, ``action``, ``log_prob``, ``value``, ``advantage``, ``target`` and, in the
    modes with a cost critic, ``cost_value``, ``cost_advantage``, ``cost_target``. In the
    Lagrangian modes the advantage is ``(A - lagrange * A_cost) / (1 + lagrange)``.
    Advantages are normalised per minibatch; value losses are clipped as in PPO2. With a
    shield's bool (B, A) ``allowed`` in ``batch``, the policy is the one that acted,
    restricted to the allowed actions, and
    ``blocked_weight`` times the unrestricted policy's probability of the blocked actions is
    added, so that the policy learns to avoid them itself. ``ent_coef`` (None: the config's)
    may be a traced per-agent value. Returns ``(loss, statistics)``.
    """
    c = config
    logits, value, cost_value = policy(
        params, batch["image"], batch["direction"], batch["sentence"]
    )
    blocked = jnp.zeros(())
    if "allowed" in batch:
        blocked = blocked_mass(logits, batch["allowed"]).mean()
        logits = mask_logits(logits, batch["allowed"])
    log_probs = jax.nn.log_softmax(logits)
    log_prob = jnp.take_along_axis(log_probs, batch["action"][:, None], axis=-1)[:, 0]
    entropy = -jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1).mean()

    adv = batch["advantage"]
    if c.mode.multiplier is not None and c.mode.policy_update == "ppo":
        adv = (adv - lagrange * batch["cost_advantage"]) / (1.0 + lagrange)
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    ratio = jnp.exp(log_prob - batch["log_prob"])
    stats = {}
    if c.mode.policy_update == "focops":
        actor_loss, stats["focops_kept"] = focops_loss(log_probs, ratio, adv, batch, lagrange, c)
    else:
        clipped = jnp.clip(ratio, 1 - c.clip_eps, 1 + c.clip_eps)
        actor_loss = -jnp.minimum(ratio * adv, clipped * adv).mean()

    def value_loss(pred, old, target):
        pred_clipped = old + jnp.clip(pred - old, -c.clip_eps, c.clip_eps)
        return 0.5 * jnp.maximum((pred - target) ** 2, (pred_clipped - target) ** 2).mean()

    v_loss = value_loss(value, batch["value"], batch["target"])
    cv_loss = jnp.zeros(())
    if c.mode.cost_critic:
        cv_loss = value_loss(cost_value, batch["cost_value"], batch["cost_target"])
    ent_coef = c.ent_coef if ent_coef is None else ent_coef
    total = actor_loss + c.vf_coef * (v_loss + cv_loss) - ent_coef * entropy
    total = total + blocked_weight * blocked
    approx_kl = jnp.mean((ratio - 1.0) - jnp.log(ratio))
    return total, {
        "loss": total, "actor_loss": actor_loss, "value_loss": v_loss,
        "cost_value_loss": cv_loss, "entropy": entropy, "approx_kl": approx_kl,
        "blocked_prob": blocked, **stats,
    }  # fmt: skip


def focops_loss(log_probs, ratio, adv, batch, nu, config) -> tuple[jax.Array, jax.Array]:
    """FOCOPS's first-order policy loss (Zhang, Vuong and Ross 2020) and the share of samples
    it keeps: the mean over samples of ``(KL - ratio * (adv - nu * cost_adv) / focops_lam)``
    where the sample's ``KL(policy || old policy)`` is at most ``focops_max_kl``, 0 elsewhere.

    Its minimiser is the old policy reweighted by ``exp((A - nu * A_cost) / focops_lam)``, the
    solution of the constrained problem in the space of policies, to which the KL term pulls
    the policy; a sample whose KL exceeds the bound gives no gradient, so that no state moves
    far in one update. ``log_probs`` (B, A) are the policy's, ``batch["logits"]`` the old
    policy's; ``adv`` is normalised, and the cost advantage too, as the paper's code does, so
    that ``nu`` weighs two advantages of one scale.
    """
    old = jax.nn.log_softmax(batch["logits"])
    kl = jnp.sum(jnp.exp(log_probs) * (log_probs - old), axis=-1)
    keep = lax.stop_gradient(kl <= config.focops_max_kl).astype(jnp.float32)
    cost_adv = batch["cost_advantage"]
    cost_adv = (cost_adv - cost_adv.mean()) / (cost_adv.std() + 1e-8)
    loss = kl - ratio * (adv - nu * cost_adv) / config.focops_lam
    return jnp.mean(loss * keep), keep.mean()


# CPO's backtracking line search: this many step sizes, each this share of the one before.
LINE_SEARCH_STEPS = 10
LINE_SEARCH_DECAY = 0.8
_EPS = 1e-8


def conjugate_gradient(matvec: Callable, rhs: jax.Array, iters: int) -> jax.Array:
    """``x`` with ``matvec(x) ~ rhs`` after ``iters`` conjugate-gradient steps (``matvec`` a
    symmetric positive-definite product), from 0; it stops improving once the residual
    vanishes. Vmappable over ``rhs``."""

    def body(_, s):
        x, r, p, rr = s
        ap = matvec(p)
        alpha = rr / jnp.maximum(p @ ap, _EPS * _EPS)
        x_new, r_new = x + alpha * p, r - alpha * ap
        rr_new = r_new @ r_new
        new = (x_new, r_new, r_new + rr_new / jnp.maximum(rr, _EPS * _EPS) * p, rr_new)
        return jax.tree.map(lambda a, b: jnp.where(rr > 1e-20, a, b), new, s)

    zeros = jnp.zeros_like(rhs)
    return lax.fori_loop(0, iters, body, (zeros, rhs, rhs, rhs @ rhs))[0]


def cpo_step(
    logits_of: Callable,
    params,
    batch: dict[str, jax.Array],
    excess,
    config: PPOConfig,
    fisher: tuple[Callable, jax.Array] | None = None,
) -> tuple[object, dict[str, jax.Array]]:
    """One CPO policy update (Achiam, Held, Tamar and Abbeel 2017) from the acting policy.

    ``logits_of(params) -> (B, A)`` are the policy's logits of the batch's samples; ``batch``
    holds (B,) ``action``, ``log_prob`` and (B, A) ``logits`` of the acting policy, and
    ``advantage`` (normalised here) and ``cost_advantage`` (centred: its scale is the cost's);
    ``excess`` is the constraint's value on the surrogates' per-step scale (the learner's: the
    cost per episode minus its limit, over the mean episode length; > 0: the policy is
    infeasible). With ``g`` and ``b`` the gradients of the reward and cost surrogates and ``F``
    the Fisher matrix, the Hessian of the mean ``KL(old || policy)`` (its products are a ``jvp``
    of its gradient, plus ``cpo_damping``; over the samples of ``fisher``, a
    ``(logits_of, old logits)`` pair of a part of the batch, where given), conjugate gradient
    gives ``F^-1 g`` and ``F^-1 b`` in ``cpo_cg_iters`` steps and the linearised problem
    (maximise ``g.x`` subject to ``x.F.x / 2 <= cpo_max_kl`` and ``excess + b.x <= 0``) is
    solved in closed form through its dual. Where no step satisfies both (``case`` 0) the step
    is the recovery one, ``-sqrt(2 cpo_max_kl / b.F^-1.b) F^-1 b``: a pure decrease of the
    cost. A backtracking line search
    (:data:`LINE_SEARCH_STEPS` sizes, each :data:`LINE_SEARCH_DECAY` of the one before) takes
    the first that keeps the measured KL within ``cpo_max_kl``, does not raise the cost
    surrogate by more than the slack ``max(-excess, 0)`` and, when the problem was feasible
    (``case`` >= 2), does not lower the reward surrogate; with none, the policy stays. Returns
    ``(params, statistics)``: ``cpo_case`` (4: no cost gradient, 3: the trust region is
    feasible, 2 and 1: the constraint binds, 0: recovery), ``cpo_step`` (the step size taken, 0:
    none), ``cpo_kl``.
    """
    c = config
    flat, unravel = ravel_pytree(params)
    old = jax.nn.log_softmax(batch["logits"])
    adv = batch["advantage"]
    adv = (adv - adv.mean()) / (adv.std() + _EPS)
    cost_adv = batch["cost_advantage"] - batch["cost_advantage"].mean()

    def surrogates(x):
        log_probs = jax.nn.log_softmax(logits_of(unravel(x)))
        log_prob = jnp.take_along_axis(log_probs, batch["action"][:, None], axis=-1)[:, 0]
        ratio = jnp.exp(log_prob - batch["log_prob"])
        kl = jnp.sum(jnp.exp(old) * (old - log_probs), axis=-1).mean()
        return jnp.stack([(ratio * adv).mean(), (ratio * cost_adv).mean()]), kl

    before, pullback = jax.vjp(lambda x: surrogates(x)[0], flat)
    g, b = jax.vmap(pullback)(jnp.eye(2, dtype=flat.dtype))[0]

    def mean_kl(x):
        if fisher is None:
            return surrogates(x)[1]
        part_of, part_old = fisher
        part_old = jax.nn.log_softmax(part_old)
        log_probs = jax.nn.log_softmax(part_of(unravel(x)))
        return jnp.sum(jnp.exp(part_old) * (part_old - log_probs), axis=-1).mean()

    _, hessian = jax.linearize(jax.grad(mean_kl), flat)
    fvp = lambda v: hessian(v) + c.cpo_damping * v  # noqa: E731
    x, p = jax.vmap(lambda v: conjugate_gradient(fvp, v, c.cpo_cg_iters))(jnp.stack([g, b]))
    delta, cost = c.cpo_max_kl, excess
    # The paper's dual is written for minimising a loss, whose gradient is -g: hence -g.p.
    q, r, s = x @ fvp(x), -(g @ p), b @ p
    big_a, big_b = q - r**2 / (s + _EPS), 2 * delta - cost**2 / (s + _EPS)
    case = jnp.where(
        (b @ b <= _EPS) & (cost < 0), 4,
        jnp.where(cost < 0, jnp.where(big_b < 0, 3, 2), jnp.where(big_b >= 0, 1, 0)),
    )  # fmt: skip
    # The dual of the linearised problem where the constraint binds (cases 1 and 2): the
    # multiplier lam of the trust region on either side of r / cost, where nu > 0 or not
    # (projected onto an empty side, its lower end: that side then loses).
    bound = r / (cost + _EPS)
    low_a, high_a = jnp.where(cost < 0, 0.0, bound), jnp.where(cost < 0, bound, jnp.inf)
    low_b, high_b = jnp.where(cost < 0, bound, 0.0), jnp.where(cost < 0, jnp.inf, bound)
    project = lambda v, low, high: jnp.maximum(low, jnp.minimum(high, v))  # noqa: E731
    lam_a = project(jnp.sqrt(jnp.maximum(big_a / big_b, 0.0)), low_a, high_a)
    lam_b = project(jnp.sqrt(q / (2 * delta)), low_b, high_b)
    f_a = -0.5 * (big_a / (lam_a + _EPS) + big_b * lam_a) - r * cost / (s + _EPS)
    f_b = -0.5 * (q / (lam_b + _EPS) + 2 * delta * lam_b)
    lam = jnp.where(f_a >= f_b, lam_a, lam_b)
    nu = jnp.maximum(lam * cost - r, 0.0) / (s + _EPS)
    step = jnp.where(
        case >= 3, jnp.sqrt(2 * delta / (q + _EPS)) * x,
        jnp.where(case >= 1, (x - nu * p) / (lam + _EPS), -jnp.sqrt(2 * delta / (s + _EPS)) * p),
    )  # fmt: skip

    def accepts(size):
        (gain, rise), kl = surrogates(flat + size * step)
        gain, rise = gain - before[0], rise - before[1]
        finite = jnp.isfinite(gain) & jnp.isfinite(rise) & jnp.isfinite(kl)
        ok = finite & (kl <= delta) & (rise <= jnp.maximum(-cost, 0.0))
        return ok & ((gain >= 0) | (case <= 1)), kl

    def search(state):
        k, _, _ = state
        size = LINE_SEARCH_DECAY ** k.astype(flat.dtype)
        ok, kl = accepts(size)
        return k + 1, jnp.where(ok, size, 0.0), jnp.where(ok, kl, 0.0)

    _, size, kl = lax.while_loop(
        lambda s: (s[0] < LINE_SEARCH_STEPS) & (s[1] == 0), search,
        (jnp.int32(0), jnp.zeros((), flat.dtype), jnp.zeros((), flat.dtype)),
    )  # fmt: skip
    stats = {"cpo_case": case.astype(jnp.float32), "cpo_step": size, "cpo_kl": kl}
    return unravel(flat + size * step), stats


class PIDState(struct.PyTreeNode):
    """The PID Lagrangian's memory between updates (float32 scalars)."""

    integral: jax.Array  # the cost error summed over the updates, clipped at 0
    cost: jax.Array  # the previous update's cost per episode


def pid_update(state: PIDState, cost: jax.Array, limit, kp, ki, kd) -> tuple[jax.Array, PIDState]:
    """The PID Lagrangian's multiplier for cost per episode ``cost`` (Stooke, Achiam and
    Abbeel 2020, their Algorithm 2 without smoothing): ``max(0, kp * e + ki * I + kd * d)``
    with ``e = cost - limit``, ``I = max(0, I + e)`` and ``d = max(0, cost - previous cost)``.

    The proportional term answers a cost at once and goes when it goes; the integral is the
    Lagrangian's multiplier (``ki`` its step size) and, clipped at 0, does not wind up while the
    cost stays under the limit; the derivative damps a rising cost only. Returns
    ``(multiplier, next state)``.
    """
    error = cost - limit
    integral = jnp.maximum(0.0, state.integral + error)
    rise = jnp.maximum(0.0, cost - state.cost)
    lagrange = jnp.maximum(0.0, kp * error + ki * integral + kd * rise)
    return lagrange.astype(jnp.float32), PIDState(
        integral=integral.astype(jnp.float32), cost=jnp.asarray(cost, jnp.float32)
    )


def shuffle(key: jax.Array, n: int) -> jax.Array:
    """A random permutation of ``range(n)`` for minibatching, from one sort of uint32.

    The low ``b = bit_length(n - 1)`` bits of each random word are replaced by the index, and
    one array of distinct words is sorted (cheaper than ``argsort``, which sorts (bits, index)
    pairs). Ties among the high ``32 - b`` random bits keep index order; a tie only changes
    which minibatch an item lands in when it straddles a minibatch boundary. Used up to
    ``n = 2**16`` (at least 16 random bits); larger batches fall back to ``argsort``.
    """
    bits = jax.random.bits(key, (n,))
    b = max(n - 1, 1).bit_length()
    if b > 16:
        return jnp.argsort(bits)
    low = jnp.uint32((1 << b) - 1)
    words = (bits & ~low) | jnp.arange(n, dtype=jnp.uint32)
    return (lax.sort(words) & low).astype(jnp.int32)
