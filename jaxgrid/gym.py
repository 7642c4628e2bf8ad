"""Gymnasium adapters: every jaxgrid id as ``jaxgrid/<id>``, single and vector.

Importing this module registers every id of :func:`jaxgrid.registered_ids` with gymnasium as
``jaxgrid/<id>`` (idempotent; call :func:`register_envs` again after registering your own ids
with :func:`jaxgrid.register`)::

    import gymnasium as gym
    import jaxgrid.gym  # registers the ids

    env = gym.make("jaxgrid/TwoRooms-v0", render_mode="rgb_array")
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

    envs = gym.make_vec("jaxgrid/TwoRooms-v0", num_envs=64, vectorization_mode="vector_entry_point")

Keyword arguments go to :func:`jaxgrid.make`, a constraint included, single and vector alike:
``gym.make("jaxgrid/MiniGrid-LavaCrossingS9N1-v0", constraint="do not step on lava more than
twice", lava="cost")`` observes ``constraint`` and reports ``cost`` and ``violation`` in
``info``.

:class:`JaxGridEnv` wraps one environment behind a jitted ``step``; :class:`JaxGridVectorEnv`
steps the whole batch in one jitted call of :class:`jaxgrid.wrappers.BatchedAutoReset`, with
gymnasium's ``AutoresetMode.SAME_STEP`` semantics. Both return numpy arrays.
"""

from __future__ import annotations

import functools

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from jaxgrid.constrained import language_table
from jaxgrid.registry import make, registered_ids
from jaxgrid.render import render, render_ansi
from jaxgrid.wrappers import BatchedAutoReset

__all__ = ["NAMESPACE", "JaxGridEnv", "JaxGridVectorEnv", "observation_space", "register_envs"]

NAMESPACE = "jaxgrid"
RENDER_MODES = ["rgb_array", "ansi"]
RENDER_FPS = 10  # MiniGrid's


def observation_space(env) -> spaces.Dict:
    """The gymnasium space of one observation of a jaxgrid environment.

    ``image``: Box uint8 ``(V, V, 3)`` in ``[0, 255]`` (MiniGrid's encoding, indexed ``[x, y]``),
    ``direction``: Discrete(4), and for constrained envs ``constraint``: Box int32 ``(MAX_LEN,)`` of
    token ids in ``[0, vocab_size)`` of the env's sentence table
    (:func:`jaxgrid.constrained.language_table`).
    """
    v = env.view_size
    obs = {
        "image": spaces.Box(0, 255, (v, v, 3), np.uint8),
        "direction": spaces.Discrete(4),
    }
    probe = jax.eval_shape(lambda k: env.reset(k)[1].observation, jax.random.PRNGKey(0))
    if "constraint" in probe:
        table = language_table(env)
        obs["constraint"] = spaces.Box(0, table.vocab_size - 1, (table.max_len,), np.int32)
    return spaces.Dict(obs)


def _to_numpy(tree):
    """Fresh numpy copies of every leaf (never views of device buffers)."""
    return jax.tree.map(lambda x: np.array(x, copy=True), tree)


def _info(info: dict) -> dict:
    """Info of one env: numpy scalars (``np.bool_``, ``np.float32``, ...) and fresh arrays."""
    return {k: v[()] if v.ndim == 0 else v for k, v in _to_numpy(info).items()}


def _check_action(space, action, *, batch: bool):
    """``action`` as numpy if it is a member of ``space``, else ``ValueError`` naming both.

    JAX arrays are read as numpy first; everything else must already be a member, as
    gymnasium's own environments require (``Discrete(7)`` rejects ``7``, ``-1``, ``2.5``, ``"2"``).
    """
    if isinstance(action, jax.Array):
        action = np.asarray(action)
    if not space.contains(action):
        what = "actions" if batch else "action"
        raise ValueError(f"{what} {action!r} ({type(action).__name__}) is not in {space}")
    return np.asarray(action)


def _warn_no_render_mode(env) -> None:
    """gymnasium's own warning for ``render()`` without a ``render_mode``, with our example."""
    if env.spec is not None:
        example = f'gym.make("{env.spec.id}", render_mode="rgb_array")'
    elif env.env_id is not None:
        example = f'{type(env).__name__}("{env.env_id}", render_mode="rgb_array")'
    else:
        example = f'{type(env).__name__}(env=..., render_mode="rgb_array")'
    gymnasium.logger.warn(
        "You are calling render method without specifying any render mode. "
        f"You can specify the render_mode at initialization, e.g. {example}"
    )


def _single_obs(obs: dict) -> dict:
    out = _to_numpy(obs)
    out["direction"] = int(out["direction"])  # a Discrete sample is a Python/numpy int
    return out


@functools.partial(jax.jit, static_argnums=0)
def _reset(env, key):
    return env.reset(key)


@functools.partial(jax.jit, static_argnums=0)
def _step(env, state, action):
    return env.step(state, action)


@functools.partial(jax.jit, static_argnums=(1, 2))
def _render(state, env, tile_size):
    return render(state, env, tile_size=tile_size)


class JaxGridEnv(gymnasium.Env):
    """One jaxgrid environment as a ``gymnasium.Env``.

    Args:
        env_id: a :func:`jaxgrid.registered_ids` id (or pass ``env=`` an environment object).
        env: an already built jaxgrid environment (e.g. from :func:`jaxgrid.from_ascii`).
        render_mode: ``None``, ``"rgb_array"`` (:func:`jaxgrid.render.render`, the view
            highlighted) or ``"ansi"`` (:func:`jaxgrid.render.render_ansi`).
        tile_size: pixels per cell for ``rgb_array``.
        **overrides: settings passed to :func:`jaxgrid.make` (e.g. ``max_steps=50``).

    Observations are dicts of numpy values (see :func:`observation_space`); actions are
    Discrete(7) (MiniGrid's). ``reset(seed=s)`` is deterministic in ``s``; ``reset()`` draws the
    episode's JAX key from the env's ``np_random``. ``info`` holds the environment's info as
    numpy values (constrained envs: ``violation``, ``cost``, ``constraint_type``,
    ``template_id``).
    The environment truncates itself at ``max_steps``, so no ``TimeLimit`` is added.
    """

    metadata = {"render_modes": RENDER_MODES, "render_fps": RENDER_FPS}

    def __init__(
        self,
        env_id: str | None = None,
        *,
        env=None,
        render_mode: str | None = None,
        tile_size: int = 32,
        **overrides,
    ):
        if (env_id is None) == (env is None):
            raise ValueError("pass exactly one of env_id and env")
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(
                f"render_mode must be one of {RENDER_MODES} or None, got {render_mode!r}"
            )
        self.jax_env = make(env_id, **overrides) if env is None else env
        self.env_id = env_id
        self.render_mode = render_mode
        self.tile_size = int(tile_size)
        self.observation_space = observation_space(self.jax_env)
        self.action_space = spaces.Discrete(self.jax_env.num_actions)
        self.state = None

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; returns ``(observation, info)``."""
        super().reset(seed=seed)
        key = jax.random.PRNGKey(int(self.np_random.integers(0, 2**31 - 1)))
        self.state, ts = _reset(self.jax_env, key)
        return _single_obs(ts.observation), _info(ts.info)

    def step(self, action):
        """One step; returns ``(observation, reward, terminated, truncated, info)``."""
        action = _check_action(self.action_space, action, batch=False)
        if self.state is None:
            raise RuntimeError("call reset() before step()")
        self.state, ts = _step(self.jax_env, self.state, jnp.asarray(action, jnp.int32))
        return (
            _single_obs(ts.observation),
            float(ts.reward),
            bool(ts.terminated),
            bool(ts.truncated),
            _info(ts.info),
        )

    def render(self):
        """The current state as an RGB array (uint8 ``(H*ts, W*ts, 3)``) or text.

        Without a ``render_mode`` it warns (as gymnasium's environments do) and returns ``None``;
        before the first ``reset`` it returns ``None``.
        """
        if self.render_mode is None:
            _warn_no_render_mode(self)
            return None
        if self.state is None:
            return None
        if self.render_mode == "ansi":
            return render_ansi(self.state)
        return np.asarray(_render(self.state, self.jax_env, self.tile_size))


@functools.partial(jax.jit, static_argnums=0)
def _vreset(env, keys):
    return env.reset(keys)


@functools.partial(jax.jit, static_argnums=0)
def _vstep(env, states, actions):
    return env.step(states, actions)


@functools.partial(jax.jit, static_argnums=(1, 2))
def _vrender(states, env, tile_size):
    return jax.vmap(lambda s: render(s, env, tile_size=tile_size))(states)


class JaxGridVectorEnv(VectorEnv):
    """``num_envs`` copies of a jaxgrid environment stepped in one jitted call.

    Auto-reset is :class:`jaxgrid.wrappers.BatchedAutoReset`'s (the same bits as
    ``vmap(AutoReset(env).step)``, fresh episodes generated only where one ended), which is
    gymnasium's
    ``AutoresetMode.SAME_STEP`` (``metadata["autoreset_mode"]``): when a sub-environment's
    episode ends, the returned observation is already the next episode's first one, and
    ``infos["final_obs"]`` (an object array, ``None`` where the episode did not end, mask
    ``infos["_final_obs"]``) holds the last observation of the episode that ended, with
    ``infos["final_info"]`` its info. One difference from gymnasium's ``SyncVectorEnv``: the
    top-level ``infos`` of an env that just reset hold the info of the step that ended the
    episode (as ``AutoReset`` returns it, e.g. ``violation``), not the reset's.

    ``reset(seed=s)`` with an int ``s`` uses keys ``jax.random.split(PRNGKey(s), num_envs)``
    (exactly what a ``jax.vmap(AutoReset(env).reset)`` user would write); a list of ints seeds
    each env with ``PRNGKey(s_i)``; no seed draws one from ``np_random``. ``render()`` returns a
    tuple of RGB frames (``rgb_array``) or strings (``ansi``).
    """

    metadata = {
        "render_modes": RENDER_MODES,
        "render_fps": RENDER_FPS,
        "autoreset_mode": AutoresetMode.SAME_STEP,
    }

    def __init__(
        self,
        env_id: str | None = None,
        num_envs: int = 1,
        *,
        env=None,
        render_mode: str | None = None,
        tile_size: int = 32,
        **overrides,
    ):
        if (env_id is None) == (env is None):
            raise ValueError("pass exactly one of env_id and env")
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive int, got {num_envs!r}")
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(
                f"render_mode must be one of {RENDER_MODES} or None, got {render_mode!r}"
            )
        base = make(env_id, **overrides) if env is None else env
        self.jax_env = BatchedAutoReset(base)
        self.env_id = env_id
        self.num_envs = num_envs
        self.render_mode = render_mode
        self.tile_size = int(tile_size)
        self.single_observation_space = observation_space(base)
        self.single_action_space = spaces.Discrete(base.num_actions)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self.states = None

    def _keys(self, seed) -> jax.Array:
        if seed is None:
            seed = int(self.np_random.integers(0, 2**31 - 1))
        if isinstance(seed, (int, np.integer)):
            return jax.random.split(jax.random.PRNGKey(int(seed)), self.num_envs)
        seeds = list(seed)
        if len(seeds) != self.num_envs:
            raise ValueError(f"got {len(seeds)} seeds for {self.num_envs} environments")
        return jnp.stack([jax.random.PRNGKey(int(s)) for s in seeds])

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        """Reset every sub-environment; returns batched ``(observations, infos)``."""
        if seed is not None:
            first = seed if isinstance(seed, (int, np.integer)) else seed[0]
            super().reset(seed=int(first))  # seeds np_random
        self.states, ts = _vreset(self.jax_env, self._keys(seed))
        info = _to_numpy(ts.info)
        info.pop("final_observation")
        return _to_numpy(ts.observation), self._batch_info(info)

    def step(self, actions):
        """Step every sub-environment with ``actions`` (int ``(num_envs,)``), auto-resetting.

        ``actions`` must be a member of ``action_space`` (``ValueError`` otherwise).
        """
        actions = _check_action(self.action_space, actions, batch=True)
        if self.states is None:
            raise RuntimeError("call reset() before step()")
        actions = jnp.asarray(actions, jnp.int32)
        self.states, ts = _vstep(self.jax_env, self.states, actions)
        ts = _to_numpy(ts)
        info = dict(ts.info)
        final_obs = info.pop("final_observation")
        done = ts.terminated | ts.truncated
        infos = self._batch_info(info)
        if done.any():
            objs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(done):
                objs[i] = _single_obs({k: v[i] for k, v in final_obs.items()})
            infos["final_obs"], infos["_final_obs"] = objs, done.copy()
            final_info = {}
            for k, v in info.items():
                final_info[k], final_info[f"_{k}"] = v.copy(), done.copy()
            infos["final_info"], infos["_final_info"] = final_info, done.copy()
        return ts.observation, ts.reward, ts.terminated, ts.truncated, infos

    def _batch_info(self, info: dict) -> dict:
        out = {}
        for k, v in info.items():
            out[k], out[f"_{k}"] = v, np.ones(self.num_envs, bool)
        return out

    def render(self):
        """A tuple of per-env frames (``rgb_array``) or strings (``ansi``).

        Without a ``render_mode`` it warns (as gymnasium's environments do) and returns ``None``;
        before the first ``reset`` it returns ``None``.
        """
        if self.render_mode is None:
            _warn_no_render_mode(self)
            return None
        if self.states is None:
            return None
        if self.render_mode == "ansi":
            return tuple(
                render_ansi(jax.tree.map(lambda x, i=i: x[i], self.states))
                for i in range(self.num_envs)
            )
        frames = np.asarray(_vrender(self.states, self.jax_env.env, self.tile_size))
        return tuple(frames)


def register_envs() -> list[str]:
    """Register every :func:`jaxgrid.registered_ids` id with gymnasium as ``jaxgrid/<id>``.

    Idempotent: ids already in gymnasium's registry are skipped. Returns the gymnasium ids
    registered by this call. Called when :mod:`jaxgrid.gym` is imported.
    """
    added = []
    for env_id in registered_ids():
        gym_id = f"{NAMESPACE}/{env_id}"
        if gym_id in gymnasium.registry:
            continue
        gymnasium.register(
            id=gym_id,
            entry_point="jaxgrid.gym:JaxGridEnv",
            vector_entry_point="jaxgrid.gym:JaxGridVectorEnv",
            kwargs={"env_id": env_id},
            disable_env_checker=False,
        )
        added.append(gym_id)
    return added


register_envs()
