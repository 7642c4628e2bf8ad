"""The pytrees every environment passes around: ``State`` and ``TimeStep``."""

from __future__ import annotations

from typing import Any

import jax
from flax import struct


@struct.dataclass
class State:
    """Full, fixed-shape state of one environment.

    Attributes:
        grid: uint8 ``(width, height, 3)``; ``grid[x, y]`` is MiniGrid's encoding of the cell,
            equal to ``minigrid_env.grid.encode()`` (the agent is not drawn in it).
        agent_pos: int32 ``(2,)``, ``(x, y)``.
        agent_dir: int32 scalar, 0 = right, 1 = down, 2 = left, 3 = up.
        carrying: uint8 ``(3,)`` encoding of the carried object; ``(1, 0, 0)`` (empty) when the
            hands are empty, which is also what the agent's own view cell shows.
        step_count: int32 scalar, steps taken in this episode.
        key: PRNG key owned by the environment (used by auto-reset and scenarios).
        extras: scenario-specific pytree (``()`` for classic levels).
    """

    grid: jax.Array
    agent_pos: jax.Array
    agent_dir: jax.Array
    carrying: jax.Array
    step_count: jax.Array
    key: jax.Array
    extras: Any = ()


@struct.dataclass
class TimeStep:
    """What the agent sees after ``reset`` or ``step``.

    ``observation`` is a dict: ``"image"`` uint8 ``(V, V, 3)`` indexed ``[x, y]`` as in MiniGrid,
    ``"direction"`` int32; scenarios add ``"constraint"``. ``discount`` is 0 only on termination
    (never on truncation), so value bootstrapping stays correct.
    """

    observation: dict
    reward: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    discount: jax.Array
    info: dict

    @property
    def done(self) -> jax.Array:
        """Episode over for either reason (terminated or truncated)."""
        return self.terminated | self.truncated
