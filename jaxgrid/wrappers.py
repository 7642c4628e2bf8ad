"""Environment wrappers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from jaxgrid.environment import Environment
from jaxgrid.types import State, TimeStep


class AutoReset(struct.PyTreeNode):
    """Gym-style same-step auto-reset.

    When a step ends the episode (terminated or truncated), the returned state and observation
    are those of a fresh episode, while ``reward``, ``terminated``, ``truncated`` and
    ``discount`` describe the step that ended; ``info["final_observation"]`` keeps the last
    observation of the finished episode (needed to bootstrap values on truncation). On steps
    that do not end an episode it equals the returned observation.

    The reset is computed on every step and selected with ``jnp.where``: under ``vmap`` a
    ``lax.cond`` would compute both sides anyway. The new episode's key is split from the
    state's key, so runs are deterministic given the key passed to :meth:`reset`.
    """

    env: Environment

    def __getattr__(self, name):
        # Static configuration (view_size, max_steps, num_actions, ...) reads through.
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)

    def reset(self, key: jax.Array) -> tuple[State, TimeStep]:
        state, ts = self.env.reset(key)
        return state, ts.replace(info={**ts.info, "final_observation": ts.observation})

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        state, ts = self.env.step(state, action)
        key, layout_key = jax.random.split(state.key)
        fresh = self.env.generate(layout_key).replace(key=key)
        done = ts.terminated | ts.truncated
        state = jax.tree.map(lambda a, b: jnp.where(done, a, b), fresh, state.replace(key=key))
        # One observation of the selected state: the fresh episode's where one began.
        obs = self.env.observe(state)
        info = {**ts.info, "final_observation": ts.observation}
        return state, ts.replace(observation=obs, info=info)
