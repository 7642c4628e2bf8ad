"""PPO written against gymnax's ``Environment`` API alone: PureJaxRL's ``ppo.py``, trimmed.

It imports nothing from jaxgrid, so training through :func:`jaxgrid.gymnax.make` tests the
adapter the way PureJaxRL-style code meets it: ``env.reset(key, params)``, the installed
gymnax's ``env.step`` (6-tuple, auto-reset), ``action_space(params).n`` and
``observation_space(params).shape``. The whole run is one jitted ``lax.scan``.
"""

from __future__ import annotations

from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax


class ActorCritic(nn.Module):
    """Separate tanh MLP heads for the policy logits and the value, PureJaxRL's."""

    num_actions: int
    hidden: int = 64

    @nn.compact
    def __call__(self, x):
        ortho = nn.initializers.orthogonal
        a = x
        for _ in range(2):
            a = nn.tanh(nn.Dense(self.hidden, kernel_init=ortho(np.sqrt(2)))(a))
        logits = nn.Dense(self.num_actions, kernel_init=ortho(0.01))(a)
        c = x
        for _ in range(2):
            c = nn.tanh(nn.Dense(self.hidden, kernel_init=ortho(np.sqrt(2)))(c))
        return logits, nn.Dense(1, kernel_init=ortho(1.0))(c).squeeze(-1)


class Transition(NamedTuple):
    done: jax.Array
    action: jax.Array
    value: jax.Array
    reward: jax.Array
    log_prob: jax.Array
    obs: jax.Array


class Config(NamedTuple):
    num_envs: int = 16
    num_steps: int = 32
    num_updates: int = 100
    update_epochs: int = 4
    num_minibatches: int = 4
    lr: float = 2.5e-3
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    ent_coef: float = 0.01
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5


def _log_prob(logits, action):
    return jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], -1)[..., 0]


def _entropy(logits):
    logp = jax.nn.log_softmax(logits)
    return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


def make_train(env, env_params, config: Config | None = None):
    """``train(key) -> metrics``: per update, the summed return and the number of episodes
    that ended during its rollout (``returns``, ``episodes``, both ``(num_updates,)``)."""
    c = Config() if config is None else config
    net = ActorCritic(env.action_space(env_params).n)
    obs_shape = env.observation_space(env_params).shape
    batch = c.num_envs * c.num_steps
    mb = batch // c.num_minibatches
    tx = optax.chain(
        optax.clip_by_global_norm(c.max_grad_norm),
        optax.adam(
            optax.linear_schedule(c.lr, 0.0, c.num_updates * c.update_epochs * c.num_minibatches),
            eps=1e-5,
        ),
    )
    reset = jax.vmap(env.reset, in_axes=(0, None))
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))

    def loss_fn(params, tr, adv, targets):
        logits, value = net.apply(params, tr.obs)
        log_prob = _log_prob(logits, tr.action)
        v_clip = tr.value + (value - tr.value).clip(-c.clip_eps, c.clip_eps)
        v_loss = 0.5 * jnp.maximum((value - targets) ** 2, (v_clip - targets) ** 2).mean()
        ratio = jnp.exp(log_prob - tr.log_prob)
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
        pg = -jnp.minimum(ratio * adv, ratio.clip(1 - c.clip_eps, 1 + c.clip_eps) * adv).mean()
        return pg + c.vf_coef * v_loss - c.ent_coef * _entropy(logits).mean()

    def gae(traj, last_value):
        def body(carry, tr):
            advantage, next_value = carry
            delta = tr.reward + c.gamma * next_value * (1 - tr.done) - tr.value
            advantage = delta + c.gamma * c.gae_lambda * (1 - tr.done) * advantage
            return (advantage, tr.value), advantage

        init = (jnp.zeros_like(last_value), last_value)
        adv = jax.lax.scan(body, init, traj, reverse=True)[1]
        return adv, adv + traj.value

    def env_step(runner, _):
        params, opt_state, obs, state, ep_return, key = runner
        key, k_act, k_step = jax.random.split(key, 3)
        logits, value = net.apply(params, obs)
        action = jax.random.categorical(k_act, logits)
        keys = jax.random.split(k_step, c.num_envs)
        obs2, state, reward, terminated, truncated, _ = step(keys, state, action, env_params)
        done = terminated | truncated
        ep_return = ep_return + reward
        ended = (jnp.where(done, ep_return, 0.0).sum(), done.sum())
        tr = Transition(
            done.astype(jnp.float32), action, value, reward, _log_prob(logits, action), obs
        )
        return (params, opt_state, obs2, state, jnp.where(done, 0.0, ep_return), key), (tr, ended)

    def update(runner, _):
        runner, (traj, ended) = jax.lax.scan(env_step, runner, None, c.num_steps)
        params, opt_state, obs, state, ep_return, key = runner
        adv, targets = gae(traj, net.apply(params, obs)[1])

        def epoch(carry, _):
            params, opt_state, key = carry
            key, k = jax.random.split(key)
            perm = jax.random.permutation(k, batch)
            flat = jax.tree.map(
                lambda x: x.reshape((batch,) + x.shape[2:])[perm], (traj, adv, targets)
            )
            mbs = jax.tree.map(lambda x: x.reshape((c.num_minibatches, mb) + x.shape[1:]), flat)

            def minibatch(carry, data):
                params, opt_state = carry
                grads = jax.grad(loss_fn)(params, *data)
                updates, opt_state = tx.update(grads, opt_state)
                return (optax.apply_updates(params, updates), opt_state), None

            (params, opt_state), _ = jax.lax.scan(minibatch, (params, opt_state), mbs)
            return (params, opt_state, key), None

        (params, opt_state, key), _ = jax.lax.scan(
            epoch, (params, opt_state, key), None, c.update_epochs
        )
        metrics = {"returns": ended[0].sum(), "episodes": ended[1].sum()}
        return (params, opt_state, obs, state, ep_return, key), metrics

    def train(key):
        k_init, k_reset, key = jax.random.split(key, 3)
        params = net.init(k_init, jnp.zeros(obs_shape, jnp.float32))
        obs, state = reset(jax.random.split(k_reset, c.num_envs), env_params)
        runner = (params, tx.init(params), obs, state, jnp.zeros(c.num_envs), key)
        return jax.lax.scan(update, runner, None, c.num_updates)[1]

    return train


def mean_return(metrics, updates: slice) -> tuple[float, int]:
    """Mean episodic return and episode count over the episodes ended in ``updates``."""
    returns = float(np.sum(metrics["returns"][updates]))
    episodes = int(np.sum(metrics["episodes"][updates]))
    return returns / max(episodes, 1), episodes
