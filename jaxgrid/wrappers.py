"""Environment wrappers: gym-style auto-reset, for one env or a whole batch.

:class:`AutoReset` wraps one env (``vmap`` it for a batch): it generates a fresh episode on
every step and selects it where the episode ended. :class:`BatchedAutoReset` steps a batch
and generates and observes fresh episodes only for the envs whose episode ended (through
:func:`masked_map`), with the same bits as ``vmap(AutoReset(env).step)``; most steps end
few episodes, so it is the one to use in training loops. :class:`WithMission` adds the
mission's token ids to every observation, for agents that read it (BabyAI-style); it goes
inside the auto-reset wrappers.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct
from jax import lax

from jaxgrid.environment import Environment
from jaxgrid.types import State, TimeStep


class WithMission(struct.PyTreeNode):
    """``env`` with ``observation["mission"]``: int32 ``(MAX_WORDS,)`` token ids of
    :meth:`~jaxgrid.environment.Environment.mission` (decode with :func:`jaxgrid.mission.decode`).

    Wrap before auto-reset, ``BatchedAutoReset(WithMission(env))``, so fresh episodes carry
    their own mission.
    """

    env: Environment

    def __getattr__(self, name):
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)

    def generate(self, key: jax.Array) -> State:
        return self.env.generate(key)

    def observe(self, state: State) -> dict:
        return {**self.env.observe(state), "mission": self.env.mission(state)}

    def reset(self, key: jax.Array) -> tuple[State, TimeStep]:
        return self._with_mission(*self.env.reset(key))

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        return self._with_mission(*self.env.step(state, action))

    def _with_mission(self, state, ts):
        obs = {**ts.observation, "mission": self.env.mission(state)}
        return state, ts.replace(observation=obs)


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


class BatchedAutoReset(struct.PyTreeNode):
    """:class:`AutoReset` over a leading env axis, resetting only the envs that ended.

    ``reset(keys)`` takes one key per env; ``step(states, actions)`` takes a batch of states
    and actions. The result has the same bits as ``vmap(AutoReset(env).step)``: the same
    keys are split the same way, but fresh episodes are generated and observed only where
    an episode ended (:func:`masked_map`), instead of for every env on every step.
    """

    env: Environment

    def __getattr__(self, name):
        if name == "env":
            raise AttributeError(name)
        return getattr(self.env, name)

    def reset(self, keys: jax.Array) -> tuple[State, TimeStep]:
        return jax.vmap(AutoReset(self.env).reset)(keys)

    def step(self, states: State, actions: jax.Array) -> tuple[State, TimeStep]:
        env = self.env
        states, ts = jax.vmap(env.step)(states, actions)
        key, layout_key = jnp.moveaxis(jax.vmap(jax.random.split)(states.key), 1, 0)
        done = ts.terminated | ts.truncated
        old = (states.replace(key=key), ts.observation)
        states, obs = masked_map(done, self._fresh, (layout_key, key), old)
        info = {**ts.info, "final_observation": ts.observation}
        return states, ts.replace(observation=obs, info=info)

    def restart(self, states: State, obs: dict, mask: jax.Array) -> tuple[State, dict]:
        """Fresh episodes where ``mask`` (an episode ended by the caller, e.g. on a
        violation), keys split from each state's key as :meth:`step` does; other envs keep
        their state and observation."""
        key, layout_key = jnp.moveaxis(jax.vmap(jax.random.split)(states.key), 1, 0)
        return masked_map(mask, self._fresh, (layout_key, key), (states, obs))

    def _fresh(self, keys):
        """Fresh episodes (state, observation) of a batch of (layout key, state key) pairs."""

        def one(layout_key, key):
            state = self.env.generate(layout_key).replace(key=key)
            return state, self.env.observe(state)

        return jax.vmap(one)(*keys)


def masked_map(mask: jax.Array, fn, inputs, other, chunk: int = 16):
    """``where(mask, fn(inputs), other)`` row by row, calling ``fn`` on the masked rows only.

    ``fn`` maps a batch (pytree, leading axis) to a batch; ``other`` is a pytree of its output
    shapes. Few envs end an episode on a given step, so the masked rows go through ``fn``
    ``chunk`` at a time in a ``while_loop``: one pass in the common case, as many as needed
    when many episodes end together (also under ``vmap``). For row-wise ``fn`` whose rows do
    not depend on the rest of the batch (env resets, the checker's frame embedding) the result
    has the same bits as computing every row; a matmul's rows (the truncation bootstrap's
    values) may round differently in the last place for another number of rows.
    """
    n = mask.shape[0]
    chunk = min(chunk, n)
    rank = jnp.cumsum(mask) - 1  # position of each masked row among the masked rows
    rows = jnp.nonzero(mask, size=n + chunk, fill_value=0)[0]  # masked rows first; the zero
    count = mask.sum()  # tail keeps every slice in range

    def body(state):
        start, out = state
        take = lax.dynamic_slice_in_dim(rows, start, chunk)
        new = fn(jax.tree.map(lambda x: x[take], inputs))
        here = mask & (rank >= start) & (rank < start + chunk)
        pick = jnp.clip(rank - start, 0, chunk - 1)

        def place(a, b):
            return jnp.where(here.reshape((n,) + (1,) * (b.ndim - 1)), a[pick], b)

        return start + chunk, jax.tree.map(place, new, out)

    return lax.while_loop(lambda s: s[0] < count, body, (jnp.int32(0), other))[1]
