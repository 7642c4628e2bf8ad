"""The environment base class: static configuration + pure ``reset``/``step``."""

from __future__ import annotations

import dataclasses
import functools
from typing import ClassVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import mission as mission_words
from jaxgrid.constants import EMPTY_CELL, NUM_ACTIONS
from jaxgrid.contents import NOTHING, Contents
from jaxgrid.dynamics import transition
from jaxgrid.observation import egocentric_view
from jaxgrid.types import State, TimeStep


class Environment(struct.PyTreeNode):
    """A MiniGrid-semantics environment.

    The object holds configuration only. Shape-defining settings are static (hashable), so
    ``jax.jit(env.step)`` compiles once; numeric settings a user may want to ``vmap`` over are
    pytree leaves declared by subclasses. Subclasses implement :meth:`generate` (the layout
    distribution) and may extend :meth:`observe` and :meth:`step`; a subclass whose layouts
    need more room than a 1x1 grid says so in :meth:`min_size`, which construction enforces.
    An overriding ``step`` should call :func:`check_action` first, as :meth:`step` does.
    A level states MiniGrid's mission in :attr:`MISSION`, or in :meth:`mission` when the
    mission names the episode's task, and what its episodes can hold in :meth:`contents`.
    """

    MISSION = "get to the green goal square"  # MiniGridEnv's most common mission
    #: What every episode of the level can hold (:meth:`contents`, when no setting changes it).
    CONTENTS: ClassVar[Contents] = NOTHING

    width: int = struct.field(pytree_node=False)
    height: int = struct.field(pytree_node=False)
    max_steps: int = struct.field(pytree_node=False)
    view_size: int = struct.field(pytree_node=False, default=7)
    see_through_walls: bool = struct.field(pytree_node=False, default=False)

    def __post_init__(self):
        _check_config(self)

    # --- to implement -------------------------------------------------------------------
    def min_size(self) -> tuple[int, int, str]:
        """``(min_width, min_height, why)``: the smallest grid (outer walls included) whose
        layouts put every object on a legal cell, and the reason, quoted in the error."""
        return 1, 1, "a grid needs a cell"

    def generate(self, key: jax.Array) -> State:
        """Sample a fresh episode's state (layout, agent pose) with ``step_count == 0``.

        ``key`` is spent on the layout alone: callers (:meth:`reset`, ``AutoReset``) replace the
        returned state's ``key`` with an independent one, which saves a split per reset.
        """
        raise NotImplementedError

    def contents(self) -> Contents:
        """What this level's episodes can hold in the kinds a constraint names (a
        :class:`~jaxgrid.contents.Contents`), at reset or later: a constraint may name only
        these. The default, :attr:`CONTENTS` (nothing, unless the level declares it), leaves
        a level unconstrainable until it declares."""
        return self.CONTENTS

    # --- public API -----------------------------------------------------------------------
    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    def reset(self, key: jax.Array) -> tuple[State, TimeStep]:
        """Start an episode: ``(state, timestep)`` with zero reward, not done.

        ``key`` is one PRNG key (``jax.random.key(s)`` or ``jax.random.PRNGKey(s)``); a concrete
        non-key raises (:func:`check_key`). ``jax.vmap(env.reset)(keys)`` resets a batch.
        """
        check_key(key)
        key, layout_key = jax.random.split(key)
        state = self.generate(layout_key).replace(key=key)
        return state, self.first_timestep(state)

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """One raw MiniGrid step (no auto-reset). Actions outside ``0..6`` act as ``done``.

        ``action`` is an integer scalar; a concrete float, string or array of another shape
        raises (:func:`check_action`). ``jax.vmap(env.step)`` steps a batch.
        """
        check_action(action)
        state, reward, terminated, truncated = transition(state, action, self.max_steps)
        return state, self.make_timestep(state, reward, terminated, truncated)

    def observe(self, state: State) -> dict:
        """MiniGrid's observation dict (without ``mission``): ``image`` and ``direction``."""
        image = egocentric_view(
            state.grid,
            state.agent_pos,
            state.agent_dir,
            state.carrying,
            self.view_size,
            self.see_through_walls,
        )
        return {"image": image, "direction": state.agent_dir}

    def mission(self, state: State) -> jax.Array:
        """MiniGrid's mission for ``state``'s episode: int32 ``(MAX_WORDS,)`` token ids of
        :mod:`jaxgrid.mission`, fixed for the episode; ``jax.vmap`` it for a batch."""
        return mission_words.fill(self.MISSION)

    def mission_text(self, state: State) -> str:
        """The mission of one (unbatched) ``state`` as MiniGrid's string."""
        if jnp.ndim(state.step_count) != 0:
            raise ValueError(
                "mission_text takes one state; for a batch, decode each row of "
                "jax.vmap(env.mission)(states) with jaxgrid.mission.decode"
            )
        return mission_words.decode(jax.device_get(self.mission(state)))

    def info(self, state: State) -> dict:
        """Extra per-step information; identical structure at reset and step."""
        return {}

    # --- helpers for subclasses -------------------------------------------------------
    def first_timestep(self, state: State) -> TimeStep:
        false = jnp.zeros((), bool)
        return self.make_timestep(state, jnp.zeros((), jnp.float32), false, false)

    def make_timestep(self, state, reward, terminated, truncated, info=None) -> TimeStep:
        """TimeStep of ``state``; ``info`` defaults to :meth:`info` (the reset-time info)."""
        return TimeStep(
            observation=self.observe(state),
            reward=reward,
            terminated=terminated,
            truncated=truncated,
            discount=1.0 - terminated.astype(jnp.float32),
            info=self.info(state) if info is None else info,
        )

    def init_state(self, grid, agent_pos, agent_dir, key, extras=()) -> State:
        """Assemble a start ``State`` (empty hands, step 0) from layout pieces."""
        return State(
            grid=jnp.asarray(grid, jnp.uint8),
            agent_pos=jnp.asarray(agent_pos, jnp.int32),
            agent_dir=jnp.asarray(agent_dir, jnp.int32),
            carrying=jnp.asarray(EMPTY_CELL),
            step_count=jnp.zeros((), jnp.int32),
            key=key,
            extras=extras,
        )


def check_action(action) -> None:
    """Raise if a concrete ``action`` is not one integer scalar; do nothing under ``jit``/``vmap``.

    A float (``2.7``), a string or a bool raises ``TypeError``; an integer array of another
    shape than ``()`` raises ``ValueError``. Traced actions are not inspected, so the jitted
    step gains no work and an out-of-range integer still acts as ``done`` everywhere.
    """
    if isinstance(action, jax.core.Tracer):
        return
    expected = "an integer scalar (a MiniGrid action 0..6; other integers act as done)"
    if isinstance(action, int) and not isinstance(action, bool):
        return
    dtype = getattr(action, "dtype", None)
    if not isinstance(action, (np.ndarray, np.generic, jax.Array)) or not jnp.issubdtype(
        dtype, jnp.integer
    ):
        what = f"{type(action).__name__} {action!r}" if dtype is None else f"dtype {dtype}"
        raise TypeError(f"step's action must be {expected}, got {what}")
    if action.shape != ():
        raise ValueError(
            f"step's action must be {expected}, got an array of shape {action.shape}; "
            "step a batch with jax.vmap(env.step)"
        )


@functools.cache
def _raw_key_shape(impl: str) -> tuple[int, ...]:
    del impl  # the cache key: the default PRNG implementation fixes the raw key's shape
    return jax.eval_shape(lambda: jax.random.PRNGKey(0)).shape


def check_key(key) -> None:
    """Raise if a concrete ``key`` is not one PRNG key; do nothing under ``jit``/``vmap``.

    Accepted: a typed key of shape ``()`` (``jax.random.key(s)``) or a raw uint32 key
    (``jax.random.PRNGKey(s)``). Anything else, e.g. the int ``0``, raises ``TypeError``;
    a key array of another shape (a batch) raises ``ValueError``.
    """
    if isinstance(key, jax.core.Tracer):
        return
    expected = "one PRNG key, e.g. jax.random.key(0) or jax.random.PRNGKey(0)"
    dtype = getattr(key, "dtype", None)
    if isinstance(key, jax.Array) and jnp.issubdtype(dtype, jax.dtypes.prng_key):
        shape = ()
    elif isinstance(key, (np.ndarray, jax.Array)) and dtype == np.uint32:
        shape = _raw_key_shape(jax.config.jax_default_prng_impl)
    else:
        what = f"{type(key).__name__} {key!r}" if dtype is None else f"an array of dtype {dtype}"
        raise TypeError(f"reset's key must be {expected}, got {what}")
    if key.shape != shape:
        raise ValueError(
            f"reset's key must be {expected} (shape {shape}), got shape {key.shape}; "
            "reset a batch with jax.vmap(env.reset)(jax.random.split(key, n))"
        )


# Declared setting types checked for every level; annotations are strings (postponed).
_CHECKED_TYPES = {"bool": bool, "int": int, "float": float}


def _expected(value, kind: type) -> str | None:
    """What a setting declared ``kind`` must be, when ``value`` is not that; else None.

    Only the mix-ups later checks would miss: a bool setting takes only True or False (the
    string "False" is truthy); an int setting refuses a bool (True == 1) and a float (5.5, or
    5.0, which ``range`` and array shapes refuse only when the level is drawn); a float setting,
    a pytree leaf that may be an array, refuses a bool and a string.
    """
    if kind is bool:
        return None if isinstance(value, bool) else "a bool (True or False)"
    if kind is int:
        return None if isinstance(value, int) and not isinstance(value, bool) else "an int"
    if isinstance(value, (bool, np.bool_, str, bytes)):
        return "a number or an array of numbers"
    return None


def check_setting_types(env: Environment) -> None:
    """Raise ``ValueError`` naming the setting and the value when a setting declared ``bool``,
    ``int`` or ``float`` holds a value of another type (see :func:`_expected`).

    Settings of other declared types (tuples, strings, optional values) are checked by their
    level. It runs at construction, so it covers ``make`` overrides and ``replace`` too.
    """
    for field in dataclasses.fields(env):
        kind = _CHECKED_TYPES.get(field.type) if isinstance(field.type, str) else field.type
        if kind not in (bool, int, float):
            continue
        value = getattr(env, field.name)
        want = _expected(value, kind)
        if want is not None:
            raise ValueError(
                f"{type(env).__name__}.{field.name} must be {want}, got {value!r} "
                f"({type(value).__name__})"
            )


def _check_config(env: Environment) -> None:
    check_setting_types(env)
    name = type(env).__name__
    for field in ("width", "height", "max_steps"):
        value = getattr(env, field)
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise ValueError(f"{name}.{field} must be a positive int, got {value!r}")
    min_width, min_height, why = env.min_size()
    for field, low in (("width", min_width), ("height", min_height)):
        value = getattr(env, field)
        if value < low:
            raise ValueError(f"{name}.{field} must be at least {low} ({why}), got {value}")
    v = env.view_size
    # At most 31: the occlusion pass holds a view row in the bits of an int32.
    if not isinstance(v, int) or v < 3 or v % 2 == 0 or v > 31:
        raise ValueError(
            f"{type(env).__name__}.view_size must be an odd int in 3..31 (MiniGrid requires odd "
            f">= 3; jaxgrid's occlusion packs a row into an int32), got {v!r}"
        )
