"""The environment base class: static configuration + pure ``reset``/``step``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from jaxgrid.constants import EMPTY_CELL, NUM_ACTIONS
from jaxgrid.dynamics import transition
from jaxgrid.observation import egocentric_view
from jaxgrid.types import State, TimeStep


class Environment(struct.PyTreeNode):
    """A MiniGrid-semantics environment.

    The object holds configuration only. Shape-defining settings are static (hashable), so
    ``jax.jit(env.step)`` compiles once; numeric settings a user may want to ``vmap`` over are
    pytree leaves declared by subclasses. Subclasses implement :meth:`generate` (the layout
    distribution) and may extend :meth:`observe` and :meth:`step`.
    """

    width: int = struct.field(pytree_node=False)
    height: int = struct.field(pytree_node=False)
    max_steps: int = struct.field(pytree_node=False)
    view_size: int = struct.field(pytree_node=False, default=7)
    see_through_walls: bool = struct.field(pytree_node=False, default=False)

    def __post_init__(self):
        _check_config(self)

    # --- to implement -------------------------------------------------------------------
    def generate(self, key: jax.Array) -> State:
        """Sample a fresh episode's state (layout, agent pose) with ``step_count == 0``.

        ``key`` is spent on the layout alone: callers (:meth:`reset`, ``AutoReset``) replace the
        returned state's ``key`` with an independent one, which saves a split per reset.
        """
        raise NotImplementedError

    # --- public API -----------------------------------------------------------------------
    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    def reset(self, key: jax.Array) -> tuple[State, TimeStep]:
        """Start an episode: ``(state, timestep)`` with zero reward, not done."""
        key, layout_key = jax.random.split(key)
        state = self.generate(layout_key).replace(key=key)
        return state, self.first_timestep(state)

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """One raw MiniGrid step (no auto-reset). Actions outside ``0..6`` act as ``done``."""
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


def _check_config(env: Environment) -> None:
    for name in ("width", "height", "max_steps"):
        value = getattr(env, name)
        if not isinstance(value, int) or isinstance(value, bool) or value < 1:
            raise ValueError(f"{type(env).__name__}.{name} must be a positive int, got {value!r}")
    v = env.view_size
    # At most 31: the occlusion pass holds a view row in the bits of an int32.
    if not isinstance(v, int) or v < 3 or v % 2 == 0 or v > 31:
        raise ValueError(
            f"{type(env).__name__}.view_size must be an odd int in 3..31 (MiniGrid requires odd "
            f">= 3; jaxgrid's occlusion packs a row into an int32), got {v!r}"
        )
