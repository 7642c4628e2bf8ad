"""Gymnax adapter: every jaxgrid id as a gymnax ``Environment``, for JAX RL code unchanged.

PureJaxRL, rejax, Stoix and purejaxql consume gymnax's ``Environment`` contract; :func:`make`
returns one, so their training loops run on jaxgrid as they do on gymnax's own envs::

    import jax
    import jaxgrid.gymnax

    env, env_params = jaxgrid.gymnax.make("MiniGrid-Empty-6x6-v0")  # or "TwoRooms-v0", ...
    keys = jax.random.split(jax.random.PRNGKey(0), 16)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(keys, env_params)   # obs: (16, 984)
    actions = jax.vmap(env.action_space(env_params).sample)(keys)
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    obs, state, reward, terminated, truncated, info = step(keys, state, actions, env_params)
    info["cost"], info["violation"]  # safe-RL signals (0.0 / False on unconstrained ids)

Observations (``observation=`` of :func:`make`):

* ``"flat"`` (default): one float32 vector in ``[0, 1]``, ``spaces.Box``. The ``(V, V, 3)``
  image, cell by cell in its ``[x, y]`` order, one-hot per channel exactly as MiniGrid's
  ``OneHotPartialObsWrapper`` (object type 11, colour 6, state 3: 20 features a cell), then the
  direction one-hot (4), then, for constrained envs, each constraint token one-hot
  over the env's vocabulary, padding (id 0) included. An MLP reads it as is; no information is
  dropped. Sizes: ``V * V * 20 + 4`` (984 for a 7x7 view), ``+ 13 * 23`` for TwoRooms-v0,
  TwoRoomsLava-v0 and ThreeRoomsKey-v0 (5x5 view: 803), ``+ 32 * 73`` for HazardRooms-v0 and
  a level made with a constraint (``make(id, constraint=...)``; its keywords go to
  :func:`jaxgrid.make`).
* ``"dict"``: jaxgrid's own observation as an :class:`Observation` (a dict that also reads
  its keys as attributes, as ``spaces.Dict.contains`` does): ``image`` uint8 ``(V, V, 3)``,
  ``direction`` int32, and for constrained envs ``constraint`` int32 token ids;
  ``spaces.Dict``.

``info`` of :meth:`GymnaxEnv.step_env`: ``cost`` (float32) and ``violation`` (bool) for
every id, as jaxgrid's own info has them (always 0.0 / False on unconstrained ids): in the
paper's scenarios ``cost`` is 1.0 on a step with a violation; in HazardRooms it is 1.0 on any
costly event, within the constraint's budget or not (the safe-RL convention, a budget being a
cost limit), as on a constrained level. The env's other info passes through (constrained
envs: ``constraint_type``, ``template_id``; HazardRooms ``satisfiable``).

The gymnax contract, chosen at import from the installed gymnax: where its ``step`` asks
``is_truncated`` (gymnax 1.0.1), ``step_env`` returns ``terminated`` alone and ``step`` returns
``(obs, state, reward, terminated, truncated, info)`` with ``info["terminated"]``,
``info["truncated"]`` and ``info["final_observation"]`` added, auto-resetting when either
is set. Earlier versions (0.0.8, 0.0.9) take ``step_env``'s flag as the episode's end and
return ``(obs, state, reward, done, info)``: there ``step_env`` returns ``done = terminated or
truncated`` and puts both flags in ``info``; their ``step`` selects the observation with one
``lax.select``, so only ``observation="flat"`` works with them. Truncation is jaxgrid's own
(the env's ``max_steps``, a static setting that also scales the reward ``1 - 0.9 t /
max_steps``) or ``env_params.max_steps_in_episode``, whichever comes first; terminated never
covers truncation, so ``1 - terminated`` is the bootstrap mask.

Randomness: ``reset``'s key seeds the episode (layout and the key jaxgrid's stochastic levels
keep in their state); ``step``'s key drives only gymnax's auto-reset. So an episode equals
``jaxgrid.make(id)`` stepped raw from ``reset`` with the same key and actions.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
from flax import struct

try:
    from gymnax.environments import environment, spaces
except ImportError as err:  # gymnax is an optional extra; name the command that installs it
    raise ImportError(f'jaxgrid.gymnax needs gymnax: pip install -e ".[gymnax]" ({err})') from err

from jaxgrid.constants import COLOR_NAMES, OBJECT_NAMES, STATE_NAMES
from jaxgrid.constrained import language_table
from jaxgrid.environment import Environment
from jaxgrid.registry import make as make_jaxgrid
from jaxgrid.types import State

__all__ = [
    "OBSERVATIONS",
    "EnvParams",
    "EnvState",
    "GymnaxEnv",
    "Observation",
    "flatten_observation",
    "make",
]

OBSERVATIONS = ("flat", "dict")
#: One-hot widths of the image's channels (object type, colour, state), MiniGrid's.
CHANNELS = (len(OBJECT_NAMES), len(COLOR_NAMES), len(STATE_NAMES))
NUM_DIRECTIONS = 4
#: gymnax versions whose ``step`` asks ``is_truncated`` keep ``step_env``'s flag as termination.
SPLIT_TRUNCATION = hasattr(environment.Environment, "is_truncated")


class Observation(dict):
    """A dict observation whose keys also read as attributes (``obs.image``).

    gymnax's ``spaces.Dict.contains`` reads ``getattr(obs, key)``; a plain dict has no such
    attributes. It is a pytree (registered below) with a plain dict's key order.
    """

    __slots__ = ()

    def __getattr__(self, name):
        try:
            return self[name]
        except KeyError:
            raise AttributeError(name) from None


def _flatten_with_keys(obs):
    keys = tuple(sorted(obs))
    return tuple((jax.tree_util.DictKey(k), obs[k]) for k in keys), keys


jax.tree_util.register_pytree_with_keys(
    Observation,
    _flatten_with_keys,
    lambda keys, values: Observation(zip(keys, values, strict=True)),
    lambda obs: (tuple(obs[k] for k in sorted(obs)), tuple(sorted(obs))),
)


@struct.dataclass
class EnvParams(environment.EnvParams):
    """gymnax's ``EnvParams``: ``max_steps_in_episode`` and the env's numeric settings.

    ``settings`` maps each setting the jaxgrid env declares as a pytree leaf (the scenarios'
    ``absent_colour_prob``) to its value, so it can be changed or ``vmap``-ed without a new
    compile; shape-defining settings stay static in the env object.
    """

    settings: dict = struct.field(default_factory=dict)


@struct.dataclass
class EnvState(environment.EnvState):
    """gymnax's ``EnvState`` (``time``: steps this episode) around jaxgrid's ``State``.

    ``terminated`` and ``truncated`` are jaxgrid's flags of the step that produced the state
    (False after a reset); gymnax's ``is_terminated``/``is_truncated`` read them.
    """

    inner: State
    terminated: jax.Array
    truncated: jax.Array


def flatten_observation(obs: dict, vocab_size: int = 0) -> jax.Array:
    """The ``"flat"`` encoding of a jaxgrid observation dict (any leading batch axes).

    One-hot image channels (type 11, colour 6, state 3 per cell, ``[x, y]`` order), one-hot
    direction, then each ``constraint`` token one-hot over ``vocab_size`` ids if present.
    Out-of-range values encode as all zeros (``jax.nn.one_hot``).
    """
    image = obs["image"].astype(jnp.int32)
    batch = image.shape[:-3]
    cells = [jax.nn.one_hot(image[..., c], n, dtype=jnp.float32) for c, n in enumerate(CHANNELS)]
    parts = [
        jnp.concatenate(cells, axis=-1).reshape(batch + (-1,)),
        jax.nn.one_hot(obs["direction"], NUM_DIRECTIONS, dtype=jnp.float32),
    ]
    if "constraint" in obs:
        tokens = jax.nn.one_hot(obs["constraint"], vocab_size, dtype=jnp.float32)
        parts.append(tokens.reshape(batch + (-1,)))
    return jnp.concatenate(parts, axis=-1)


def _check_observation(observation) -> None:
    if observation not in OBSERVATIONS:
        raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
    if observation == "dict" and not SPLIT_TRUNCATION:
        raise ValueError(
            'observation="dict" needs a gymnax whose step tree-maps observations (1.0.1 '
            'does); this one selects one array: use observation="flat"'
        )


def _numeric_settings(env: Environment) -> dict:
    """The env's settings that are pytree leaves (numeric, ``vmap``-able), by name."""
    return {
        f.name: getattr(env, f.name)
        for f in dataclasses.fields(env)
        if f.metadata.get("pytree_node", True)
    }


class GymnaxEnv(environment.Environment):
    """A jaxgrid environment behind gymnax's ``Environment`` API (see the module docstring).

    Args:
        env: a jaxgrid environment (from :func:`jaxgrid.make`, :func:`jaxgrid.from_ascii`, ...).
        observation: ``"flat"`` (float32 vector) or ``"dict"`` (:class:`Observation`).
        name: what :attr:`name` reports (:func:`make` passes the id).

    The object holds static configuration only and hashes by identity, as gymnax's ``step``
    and ``reset`` are jitted with ``self`` static: build it once, outside the training loop.
    """

    def __init__(self, env: Environment, *, observation: str = "flat", name: str | None = None):
        _check_observation(observation)
        self.jax_env = env
        self.observation = observation
        self._name = type(env).__name__ if name is None else name
        # The sentence table of its tokens (the paper's, HazardRooms' own); others have none.
        self.language_table = language_table(env)

    # --- gymnax API -----------------------------------------------------------------------
    @property
    def name(self) -> str:
        return self._name

    @property
    def num_actions(self) -> int:
        return self.jax_env.num_actions

    @property
    def default_params(self) -> EnvParams:
        return EnvParams(
            max_steps_in_episode=self.jax_env.max_steps,
            settings=_numeric_settings(self.jax_env),
        )

    def reset_env(self, key: jax.Array, params: EnvParams):
        """A fresh episode of jaxgrid's ``reset(key)``: ``(obs, state)``."""
        inner, ts = self._configured(params).reset(key)
        false = jnp.zeros((), bool)
        state = EnvState(time=inner.step_count, inner=inner, terminated=false, truncated=false)
        return self._encode(ts.observation), state

    def step_env(self, key: jax.Array, state: EnvState, action, params: EnvParams):
        """jaxgrid's raw step: ``(obs, state, reward, terminated, info)`` (see the module
        docstring for gymnax versions before ``is_truncated``). ``key`` is unused: stochastic
        levels draw from the key in jaxgrid's state."""
        del key
        inner, ts = self._configured(params).step(state.inner, action)
        new = EnvState(
            time=inner.step_count, inner=inner, terminated=ts.terminated, truncated=ts.truncated
        )
        info = _info(ts.info)
        obs = self._encode(ts.observation)
        if SPLIT_TRUNCATION:
            return obs, new, ts.reward, ts.terminated, info
        truncated = self.is_truncated(new, params)
        info = {**info, "terminated": ts.terminated, "truncated": truncated}
        return obs, new, ts.reward, ts.terminated | truncated, info

    def is_terminated(self, state: EnvState, params: EnvParams) -> jax.Array:
        return state.terminated

    def is_terminal(self, state: EnvState, params: EnvParams) -> jax.Array:
        # gymnax's meaning: natural termination once is_truncated exists, the episode's end before.
        if SPLIT_TRUNCATION:
            return state.terminated
        return state.terminated | self.is_truncated(state, params)

    def is_truncated(self, state: EnvState, params: EnvParams) -> jax.Array:
        return state.truncated | (state.time >= params.max_steps_in_episode)

    def discount(self, state: EnvState, params: EnvParams) -> jax.Array:
        return 1.0 - state.terminated.astype(jnp.float32)

    def action_space(self, params: EnvParams | None = None) -> spaces.Discrete:
        return spaces.Discrete(self.num_actions)

    def observation_space(self, params: EnvParams | None = None) -> spaces.Space:
        """``spaces.Box`` of the flat vector, or ``spaces.Dict`` of the dict observation."""
        return self._spaces[self.observation]

    # --- helpers --------------------------------------------------------------------------
    def _configured(self, params: EnvParams) -> Environment:
        """The jaxgrid env with ``params``' numeric settings (traced values under ``jit``)."""
        return self.jax_env.replace(**params.settings) if params.settings else self.jax_env

    def _encode(self, obs: dict):
        if self.observation == "dict":
            return Observation(obs)
        return flatten_observation(obs, self.language_table.vocab_size)

    @functools.cached_property
    def _spaces(self) -> dict:
        probe = _observed_keys(self.jax_env)
        extra = sorted(set(probe) - {"image", "direction", "constraint"})
        if extra:
            raise ValueError(f"{self.name} observes {extra}, which this adapter does not encode")
        v = self.jax_env.view_size
        obs = {
            "image": spaces.Box(0, 255, (v, v, 3), jnp.uint8),
            "direction": spaces.Discrete(NUM_DIRECTIONS),
        }
        size = v * v * sum(CHANNELS) + NUM_DIRECTIONS
        if "constraint" in probe:
            n, vocab = self.language_table.max_len, self.language_table.vocab_size
            obs["constraint"] = spaces.Box(0, vocab - 1, (n,), jnp.int32)
            size += n * vocab
        return {"flat": spaces.Box(0.0, 1.0, (size,), jnp.float32), "dict": spaces.Dict(obs)}


def _observed_keys(env: Environment) -> frozenset:
    """The keys ``env`` observes, from an abstract reset: traced, never compiled, and cached
    for equal (hashable) envs, so making an id in both observation modes traces it once."""
    try:
        hash(env)
    except TypeError:  # array-valued settings: not hashable, nothing to share
        return _trace_observed_keys(env)
    return _cached_observed_keys(env)


def _trace_observed_keys(env: Environment) -> frozenset:
    return frozenset(jax.eval_shape(lambda: env.reset(jax.random.PRNGKey(0))[1].observation))


_cached_observed_keys = functools.lru_cache(maxsize=128)(_trace_observed_keys)


def _info(info: dict) -> dict:
    """``cost`` and ``violation`` for every env: its own where it has them, else 0.0 and
    False (an unconstrained level); its other keys pass through."""
    info = dict(info)
    violation = jnp.asarray(info.pop("violation", False), bool)
    cost = jnp.asarray(info.pop("cost", violation), jnp.float32)
    return {**info, "cost": cost, "violation": violation}


def make(env_id: str, *, observation: str = "flat", **overrides) -> tuple[GymnaxEnv, EnvParams]:
    """``(env, env_params)`` for a :func:`jaxgrid.registered_ids` id, gymnax's convention.

    ``observation`` is ``"flat"`` or ``"dict"``; ``overrides`` go to :func:`jaxgrid.make`
    (e.g. ``max_steps=50``, which also sets ``env_params.max_steps_in_episode``). An unknown
    id, setting or observation raises ``ValueError`` before anything is traced or compiled.
    """
    _check_observation(observation)
    env = GymnaxEnv(make_jaxgrid(env_id, **overrides), observation=observation, name=env_id)
    return env, env.default_params
