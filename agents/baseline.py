"""The PureJaxRL-style PPO learner: our PPO's speed reference, and this machine's baseline.

One thing, the reference learner with its env stack and its measurement, hence its length.
The comparison point for our fused PPO is "PureJaxRL's PPO (its ``ppo_minigrid`` on
Navix-DoorKey-8x8)". PureJaxRL is not on PyPI, so this module re-implements the algorithm
structure of PureJaxRL's ``ppo.py`` / ``ppo_minigrid.py`` (written from its public design,
not copied), self-contained on jax + flax + optax:

* ``make_train(config) -> train(rng)``, with PureJaxRL's upper-case config keys;
* the whole run is one ``lax.scan`` over updates; each update is a ``lax.scan`` over
  ``NUM_STEPS`` env steps of ``vmap(env.step)`` over ``NUM_ENVS`` envs, GAE by a reverse
  ``lax.scan`` (``unroll=16``), then ``UPDATE_EPOCHS`` x ``NUM_MINIBATCHES`` minibatch
  updates as a ``lax.scan`` over epochs (each re-shuffling the flattened batch with
  ``jax.random.permutation``) around a ``lax.scan`` over minibatches;
* ``ActorCritic``: separate actor and critic MLPs (2 x 64, tanh) in one flax module,
  hidden layers ``orthogonal(sqrt(2))``, actor head ``orthogonal(0.01)``, critic head
  ``orthogonal(1.0)``, zero biases; categorical policy over logits;
* loss: clipped surrogate with per-minibatch advantage normalisation, clipped value loss
  (``0.5 * max(unclipped, clipped)``), entropy bonus; ``VF_COEF`` 0.5, ``ENT_COEF`` 0.01,
  ``CLIP_EPS`` 0.2;
* ``optax.chain(clip_by_global_norm(0.5), adam(lr, eps=1e-5))`` with PureJaxRL's linear
  annealing schedule ``LR * (1 - (count // (NUM_MINIBATCHES * UPDATE_EPOCHS)) /
  NUM_UPDATES)``; LR 2.5e-4, GAMMA 0.99, GAE_LAMBDA 0.95;
* the env stack of ``ppo_minigrid``: ``NavixGymnaxWrapper`` (``navix.make(name)``, obs =
  ``timestep.observation``, done = ``timestep.is_done()``, the Timestep is the env
  state) -> ``FlattenObservationWrapper`` -> ``LogWrapper`` (episode return/length
  bookkeeping in ``info``). NAVIX auto-resets inside ``Environment.step``.

A jaxgrid id as ``ENV_NAME`` (e.g. ``MiniGrid-DoorKey-8x8-v0``) runs the same learner on
jaxgrid, its egocentric 7x7x3 view flattened (:class:`JaxgridGymnaxEnv`);
:func:`machine_baseline` falls back to it where NAVIX cannot be imported.

Env: ``navix.make("Navix-DoorKey-8x8-v0", observation_fn=navix.observations.symbolic)``,
i.e. the fully observable symbolic 8x8x3 uint8 grid flattened to 192 values (symbolic is
also that env's default observation, which is what PureJaxRL's wrapper gets). The uint8
observation is stored as such in the rollout buffer and promoted to float32 by the first
``nn.Dense``, as in PureJaxRL. NAVIX's ``make`` default ``max_steps=100`` is kept (MiniGrid's
own DoorKey-8x8 limit would be 640), because PureJaxRL's wrapper calls ``navix.make(name)``
without overriding it.

Deviations from PureJaxRL (none changes the amount of work per env step materially):

* no ``distrax``: the categorical policy is an equivalent few lines of ``jax.nn``
  (``jax.random.categorical`` sampling, ``log_softmax`` log-prob and entropy); distrax's
  per-sample validity check (``where(all(isfinite(probs)), draw, -1)``) is omitted;
* no ``gymnax``: the wrappers are small local classes with the same gymnax-style
  ``reset(key, params)`` / ``step(key, state, action, params)`` interface;
* ``train`` also returns the per-minibatch loss terms (``loss_info``; PureJaxRL computes
  and stacks them but drops them), and ``NUM_UPDATES`` is an ``int``;
* the env and the network are injectable (``make_train(config, env=..., network=...)``)
  so the same harness can run another env or model; the defaults are the above.

``python -m benchmarks.purejaxrl_ppo`` times it from the command line; experiments print
:func:`machine_baseline` beside their run time.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from flax.linen.initializers import constant, orthogonal
from flax.training.train_state import TrainState

from agents.timing import measure as timed_run

DEFAULT_ENV = "Navix-DoorKey-8x8-v0"

# PureJaxRL's ppo.py defaults with the sizes of the comparison (256 x 128, 4 x 8).
DEFAULT_CONFIG: dict[str, Any] = {
    "LR": 2.5e-4,
    "NUM_ENVS": 256,
    "NUM_STEPS": 128,
    "TOTAL_TIMESTEPS": 2_000_000,
    "UPDATE_EPOCHS": 4,
    "NUM_MINIBATCHES": 8,
    "GAMMA": 0.99,
    "GAE_LAMBDA": 0.95,
    "CLIP_EPS": 0.2,
    "ENT_COEF": 0.01,
    "VF_COEF": 0.5,
    "MAX_GRAD_NORM": 0.5,
    "ACTIVATION": "tanh",
    "ENV_NAME": DEFAULT_ENV,
    "ANNEAL_LR": True,
}


# --------------------------------------------------------------------------- env stack


class NavixGymnaxEnv:
    """A NAVIX env behind the gymnax-style interface PureJaxRL's wrappers expect.

    The NAVIX ``Timestep`` is the env state; ``step`` ignores its key (NAVIX keeps its own
    key in the state) and auto-resets on the step after a terminal/truncated timestep.
    """

    def __init__(self, env_name: str = DEFAULT_ENV, **make_kwargs: Any):
        import navix

        make_kwargs.setdefault("observation_fn", navix.observations.symbolic)
        self.name = env_name
        self._env = navix.make(env_name, **make_kwargs)  # max_steps: navix default (100)

    @property
    def max_steps(self) -> int:
        return int(self._env.max_steps)

    def reset(self, key, params=None):
        timestep = self._env.reset(key)
        return timestep.observation, timestep

    def step(self, key, state, action, params=None):
        timestep = self._env.step(state, action)
        return timestep.observation, timestep, timestep.reward, timestep.is_done(), {}

    def observation_shape(self, params=None) -> tuple[int, ...]:
        return tuple(self._env.observation_space.shape)

    def num_actions(self, params=None) -> int:
        return int(self._env.action_space.maximum) + 1


class JaxgridGymnaxEnv:
    """A jaxgrid env behind the same gymnax-style interface, for the same learner on our env.

    The observation is the agent's egocentric ``image`` (the view MiniGrid gives agents;
    uint8, ``view_size x view_size x 3``); :class:`jaxgrid.wrappers.AutoReset` resets on the
    step that ends an episode, as NAVIX does. The env's own ``max_steps`` is kept.
    """

    def __init__(self, env_name: str):
        import jaxgrid
        from jaxgrid.wrappers import AutoReset

        self.name = env_name
        self._env = AutoReset(jaxgrid.make(env_name))

    @property
    def max_steps(self) -> int:
        return int(self._env.max_steps)

    def reset(self, key, params=None):
        state, ts = self._env.reset(key)
        return ts.observation["image"], state

    def step(self, key, state, action, params=None):
        state, ts = self._env.step(state, action)
        done = ts.terminated | ts.truncated
        return ts.observation["image"], state, ts.reward, done, {}

    def observation_shape(self, params=None) -> tuple[int, ...]:
        return (self._env.view_size, self._env.view_size, 3)

    def num_actions(self, params=None) -> int:
        return int(self._env.num_actions)


class Wrapper:
    """Base of the gymnax-style wrappers: attribute access falls through to the env."""

    def __init__(self, env):
        self._env = env

    def __getattr__(self, name):
        return getattr(self._env, name)


class FlattenObservation(Wrapper):
    """Reshape each (unbatched) observation to a vector, keeping its dtype."""

    def observation_shape(self, params=None) -> tuple[int, ...]:
        return (int(np.prod(self._env.observation_shape(params))),)

    def reset(self, key, params=None):
        obs, state = self._env.reset(key, params)
        return jnp.reshape(obs, (-1,)), state

    def step(self, key, state, action, params=None):
        obs, state, reward, done, info = self._env.step(key, state, action, params)
        return jnp.reshape(obs, (-1,)), state, reward, done, info


class LogEnvState(struct.PyTreeNode):
    env_state: Any
    episode_returns: jax.Array
    episode_lengths: jax.Array
    returned_episode_returns: jax.Array
    returned_episode_lengths: jax.Array
    timestep: jax.Array


class LogWrapper(Wrapper):
    """Running episode return/length; the last finished episode's, exported in ``info``."""

    def reset(self, key, params=None):
        obs, env_state = self._env.reset(key, params)
        zf, zi = jnp.zeros((), jnp.float32), jnp.zeros((), jnp.int32)
        return obs, LogEnvState(env_state, zf, zi, zf, zi, zi)

    def step(self, key, state, action, params=None):
        obs, env_state, reward, done, info = self._env.step(key, state.env_state, action, params)
        new_return = state.episode_returns + reward
        new_length = state.episode_lengths + 1
        not_done = 1 - done.astype(jnp.int32)
        state = LogEnvState(
            env_state=env_state,
            episode_returns=new_return * not_done,
            episode_lengths=new_length * not_done,
            returned_episode_returns=jnp.where(done, new_return, state.returned_episode_returns),
            returned_episode_lengths=jnp.where(done, new_length, state.returned_episode_lengths),
            timestep=state.timestep + 1,
        )
        info = dict(info)
        info["returned_episode_returns"] = state.returned_episode_returns
        info["returned_episode_lengths"] = state.returned_episode_lengths
        info["timestep"] = state.timestep
        info["returned_episode"] = done
        return obs, state, reward, done, info


def make_env(env_name: str = DEFAULT_ENV, **make_kwargs: Any):
    """PureJaxRL ``ppo_minigrid``'s stack: env -> FlattenObservation -> LogWrapper.

    ``Navix-*`` ids are NAVIX envs (the baseline as PureJaxRL runs it); any other id is a
    :func:`jaxgrid.make` id (the same learner on our env; ``make_kwargs`` are NAVIX's only).
    """
    if env_name.startswith("Navix-"):
        inner = NavixGymnaxEnv(env_name, **make_kwargs)
    else:
        if make_kwargs:
            raise ValueError(f"make_kwargs apply to NAVIX ids only, got {sorted(make_kwargs)}")
        inner = JaxgridGymnaxEnv(env_name)
    return LogWrapper(FlattenObservation(inner))


# ----------------------------------------------------------------------------- network


class Categorical(NamedTuple):
    """The three things PPO needs from ``distrax.Categorical(logits=...)``."""

    logits: jax.Array

    def sample(self, seed: jax.Array) -> jax.Array:
        return jax.random.categorical(seed, self.logits, axis=-1)

    def log_prob(self, action: jax.Array) -> jax.Array:
        logp = jax.nn.log_softmax(self.logits, axis=-1)
        return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), -1)[..., 0]

    def entropy(self) -> jax.Array:
        logp = jax.nn.log_softmax(self.logits, axis=-1)
        return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


class ActorCritic(nn.Module):
    """Separate actor and critic MLPs (2 x 64) as in PureJaxRL; returns (pi, value)."""

    action_dim: int
    activation: str = "tanh"
    hidden: int = 64

    @nn.compact
    def __call__(self, x):
        act = nn.relu if self.activation == "relu" else nn.tanh
        dense = lambda n, scale: nn.Dense(  # noqa: E731
            n, kernel_init=orthogonal(scale), bias_init=constant(0.0)
        )
        a = act(dense(self.hidden, np.sqrt(2))(x))
        a = act(dense(self.hidden, np.sqrt(2))(a))
        logits = dense(self.action_dim, 0.01)(a)
        c = act(dense(self.hidden, np.sqrt(2))(x))
        c = act(dense(self.hidden, np.sqrt(2))(c))
        value = dense(1, 1.0)(c)
        return Categorical(logits), jnp.squeeze(value, axis=-1)


# ------------------------------------------------------------------------------- train


class Transition(NamedTuple):
    done: jax.Array
    action: jax.Array
    value: jax.Array
    reward: jax.Array
    log_prob: jax.Array
    obs: jax.Array
    info: dict


def resolve_config(config: dict[str, Any]) -> dict[str, Any]:
    """``config`` over :data:`DEFAULT_CONFIG`, plus the derived ``NUM_UPDATES`` and
    ``MINIBATCH_SIZE``; ``ValueError`` for sizes that make no whole update or minibatch."""
    config = {**DEFAULT_CONFIG, **config}
    config["NUM_UPDATES"] = int(
        config["TOTAL_TIMESTEPS"] // config["NUM_STEPS"] // config["NUM_ENVS"]
    )
    config["MINIBATCH_SIZE"] = config["NUM_ENVS"] * config["NUM_STEPS"] // config["NUM_MINIBATCHES"]
    if config["NUM_UPDATES"] < 1:
        raise ValueError("TOTAL_TIMESTEPS must cover at least one NUM_ENVS x NUM_STEPS")
    if config["MINIBATCH_SIZE"] * config["NUM_MINIBATCHES"] != (
        config["NUM_ENVS"] * config["NUM_STEPS"]
    ):
        raise ValueError("NUM_ENVS * NUM_STEPS must be divisible by NUM_MINIBATCHES")
    return config


def make_train(
    config: dict[str, Any],
    env=None,
    network: Callable[[int, str], nn.Module] | None = None,
    env_params=None,
):
    """PureJaxRL's ``make_train``: returns a pure ``train(rng)`` to jit.

    ``env`` is any gymnax-style env (``reset``, ``step``, ``observation_shape``,
    ``num_actions``; see ``make_env``), default ``make_env(config["ENV_NAME"])``.
    ``network(action_dim, activation)`` builds a flax module mapping a batch of
    observations to ``(pi, value)``, default ``ActorCritic``.
    """
    config = resolve_config(config)
    env = make_env(config["ENV_NAME"]) if env is None else env
    network = ActorCritic if network is None else network

    def linear_schedule(count):
        frac = (
            1.0
            - (count // (config["NUM_MINIBATCHES"] * config["UPDATE_EPOCHS"]))
            / config["NUM_UPDATES"]
        )
        return config["LR"] * frac

    def train(rng):
        # INIT NETWORK
        net = network(env.num_actions(env_params), config["ACTIVATION"])
        rng, _rng = jax.random.split(rng)
        init_x = jnp.zeros(env.observation_shape(env_params))
        network_params = net.init(_rng, init_x)
        lr = linear_schedule if config["ANNEAL_LR"] else config["LR"]
        tx = optax.chain(
            optax.clip_by_global_norm(config["MAX_GRAD_NORM"]),
            optax.adam(learning_rate=lr, eps=1e-5),
        )
        train_state = TrainState.create(apply_fn=net.apply, params=network_params, tx=tx)

        # INIT ENV
        rng, _rng = jax.random.split(rng)
        reset_rng = jax.random.split(_rng, config["NUM_ENVS"])
        obsv, env_state = jax.vmap(env.reset, in_axes=(0, None))(reset_rng, env_params)

        # TRAIN LOOP
        def _update_step(runner_state, unused):
            # COLLECT TRAJECTORIES
            def _env_step(runner_state, unused):
                train_state, env_state, last_obs, rng = runner_state
                # SELECT ACTION
                rng, _rng = jax.random.split(rng)
                pi, value = net.apply(train_state.params, last_obs)
                action = pi.sample(seed=_rng)
                log_prob = pi.log_prob(action)
                # STEP ENV
                rng, _rng = jax.random.split(rng)
                rng_step = jax.random.split(_rng, config["NUM_ENVS"])
                obsv, env_state, reward, done, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                    rng_step, env_state, action, env_params
                )
                transition = Transition(done, action, value, reward, log_prob, last_obs, info)
                return (train_state, env_state, obsv, rng), transition

            runner_state, traj_batch = jax.lax.scan(
                _env_step, runner_state, None, config["NUM_STEPS"]
            )

            # CALCULATE ADVANTAGE
            train_state, env_state, last_obs, rng = runner_state
            _, last_val = net.apply(train_state.params, last_obs)

            def _calculate_gae(traj_batch, last_val):
                def _get_advantages(gae_and_next_value, transition):
                    gae, next_value = gae_and_next_value
                    not_done = 1.0 - transition.done
                    delta = (
                        transition.reward
                        + config["GAMMA"] * next_value * not_done
                        - transition.value
                    )
                    gae = delta + config["GAMMA"] * config["GAE_LAMBDA"] * not_done * gae
                    return (gae, transition.value), gae

                _, advantages = jax.lax.scan(
                    _get_advantages,
                    (jnp.zeros_like(last_val), last_val),
                    traj_batch,
                    reverse=True,
                    unroll=16,
                )
                return advantages, advantages + traj_batch.value

            advantages, targets = _calculate_gae(traj_batch, last_val)

            # UPDATE NETWORK
            def _update_epoch(update_state, unused):
                def _update_minbatch(train_state, batch_info):
                    traj_batch, advantages, targets = batch_info

                    def _loss_fn(params, traj_batch, gae, targets):
                        # RERUN NETWORK
                        pi, value = net.apply(params, traj_batch.obs)
                        log_prob = pi.log_prob(traj_batch.action)

                        # CALCULATE VALUE LOSS
                        value_pred_clipped = traj_batch.value + (value - traj_batch.value).clip(
                            -config["CLIP_EPS"], config["CLIP_EPS"]
                        )
                        value_losses = jnp.square(value - targets)
                        value_losses_clipped = jnp.square(value_pred_clipped - targets)
                        value_loss = 0.5 * jnp.maximum(value_losses, value_losses_clipped).mean()

                        # CALCULATE ACTOR LOSS
                        ratio = jnp.exp(log_prob - traj_batch.log_prob)
                        gae = (gae - gae.mean()) / (gae.std() + 1e-8)
                        loss_actor1 = ratio * gae
                        loss_actor2 = (
                            jnp.clip(ratio, 1.0 - config["CLIP_EPS"], 1.0 + config["CLIP_EPS"])
                            * gae
                        )
                        loss_actor = -jnp.minimum(loss_actor1, loss_actor2).mean()
                        entropy = pi.entropy().mean()

                        total_loss = (
                            loss_actor
                            + config["VF_COEF"] * value_loss
                            - config["ENT_COEF"] * entropy
                        )
                        return total_loss, (value_loss, loss_actor, entropy)

                    grad_fn = jax.value_and_grad(_loss_fn, has_aux=True)
                    total_loss, grads = grad_fn(train_state.params, traj_batch, advantages, targets)
                    train_state = train_state.apply_gradients(grads=grads)
                    return train_state, total_loss

                train_state, traj_batch, advantages, targets, rng = update_state
                rng, _rng = jax.random.split(rng)
                # Batching and Shuffling
                batch_size = config["MINIBATCH_SIZE"] * config["NUM_MINIBATCHES"]
                permutation = jax.random.permutation(_rng, batch_size)
                batch = (traj_batch, advantages, targets)
                batch = jax.tree_util.tree_map(
                    lambda x: x.reshape((batch_size,) + x.shape[2:]), batch
                )
                shuffled_batch = jax.tree_util.tree_map(
                    lambda x: jnp.take(x, permutation, axis=0), batch
                )
                # Mini-batch Updates
                minibatches = jax.tree_util.tree_map(
                    lambda x: jnp.reshape(x, (config["NUM_MINIBATCHES"], -1) + x.shape[1:]),
                    shuffled_batch,
                )
                train_state, total_loss = jax.lax.scan(_update_minbatch, train_state, minibatches)
                update_state = (train_state, traj_batch, advantages, targets, rng)
                return update_state, total_loss

            update_state = (train_state, traj_batch, advantages, targets, rng)
            update_state, loss_info = jax.lax.scan(
                _update_epoch, update_state, None, config["UPDATE_EPOCHS"]
            )
            train_state = update_state[0]
            metric = traj_batch.info
            rng = update_state[-1]
            runner_state = (train_state, env_state, last_obs, rng)
            return runner_state, (metric, loss_info)

        rng, _rng = jax.random.split(rng)
        runner_state = (train_state, env_state, obsv, _rng)
        runner_state, (metric, loss_info) = jax.lax.scan(
            _update_step, runner_state, None, config["NUM_UPDATES"]
        )
        return {"runner_state": runner_state, "metrics": metric, "loss_info": loss_info}

    return train


# ----------------------------------------------------------------------------- measure


def device_description() -> str:
    """The machine a figure was measured on: the CPU cores visible, or the accelerator's
    kind and count."""
    dev = jax.devices()[0]
    if dev.platform == "cpu":
        return f"cpu ({os.cpu_count()} cores visible)"
    return f"{dev.platform}: {dev.device_kind}" + (
        f" x{jax.device_count()}" if jax.device_count() > 1 else ""
    )


def measure(
    total_timesteps: int = 2_000_000,
    num_envs: int = 256,
    num_steps: int = 128,
    update_epochs: int = 4,
    num_minibatches: int = 8,
    seed: int = 0,
    env=None,
    network=None,
    env_name: str = DEFAULT_ENV,
    return_output: bool = False,
) -> dict[str, Any]:
    """Compile ``train`` (timed), then time one run of it (:func:`agents.timing.measure`);
    env steps/s exclude compile.

    ``total_timesteps`` is the number actually run: ``NUM_UPDATES * num_envs *
    num_steps`` (the request rounded down to whole updates, as PureJaxRL does).
    With ``return_output`` the train output is returned under ``"output"``.
    """
    config = {
        "TOTAL_TIMESTEPS": total_timesteps,
        "NUM_ENVS": num_envs,
        "NUM_STEPS": num_steps,
        "UPDATE_EPOCHS": update_epochs,
        "NUM_MINIBATCHES": num_minibatches,
        "ENV_NAME": env_name,
    }
    train = make_train(config, env=env, network=network)
    timing = timed_run(train, jax.random.PRNGKey(seed), repeats=1)
    steps = (total_timesteps // num_steps // num_envs) * num_steps * num_envs
    result = {
        "sps": timing.rate(steps),
        "compile_s": timing.compile_s,
        "total_timesteps": int(steps),
        "device": device_description(),
        "run_s": timing.median_s,
    }
    if return_output:
        result["output"] = timing.output
    return result


def impl_name(env_name: str) -> str:
    """How results name the learner on ``env_name``: on NAVIX, or on jaxgrid."""
    return "purejaxrl-navix" if env_name.startswith("Navix-") else "purejaxrl-jaxgrid"


def machine_baseline(timesteps: int = 2**19) -> dict[str, Any]:
    """This machine's reference figure: the PureJaxRL-style learner's steps/s at the default
    sizes, on NAVIX DoorKey-8x8 where NAVIX imports, else on jaxgrid's DoorKey-8x8 (``env``
    says which). Experiments print it beside their run time, so that run times from
    different machines can be compared."""
    try:
        import navix  # noqa: F401

        env_name = DEFAULT_ENV
    except Exception:  # not installed, or not importable with this jax
        env_name = "MiniGrid-DoorKey-8x8-v0"
    res = measure(total_timesteps=timesteps, env_name=env_name)
    return {"impl": impl_name(env_name), "env": env_name, "sps": round(res["sps"], 1),
            "compile_s": round(res["compile_s"], 2), "device": res["device"],
            "timesteps": res["total_timesteps"]}  # fmt: skip
