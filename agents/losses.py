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
    policy's; ``adv`` is normalised, the cost advantage only centred (a batch with no cost
    must not be blown up to unit scale).
    """
    old = jax.nn.log_softmax(batch["logits"])
    kl = jnp.sum(jnp.exp(log_probs) * (log_probs - old), axis=-1)
    keep = lax.stop_gradient(kl <= config.focops_max_kl).astype(jnp.float32)
    cost_adv = batch["cost_advantage"] - batch["cost_advantage"].mean()
    loss = kl - ratio * (adv - nu * cost_adv) / config.focops_lam
    return jnp.mean(loss * keep), keep.mean()


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
