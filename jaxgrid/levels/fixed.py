"""A level whose every episode starts from one fixed state (ASCII maps, converted MiniGrid envs)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxgrid import mission as mission_words
from jaxgrid.constants import DOOR, EMPTY, FLOOR, GOAL, LAVA, OBJECT_NAMES, OPEN
from jaxgrid.contents import Contents
from jaxgrid.environment import Environment
from jaxgrid.types import State


class FixedLevel(Environment):
    """Resets to the same grid, agent pose and carried object every time.

    The layout is stored as static bytes so the environment stays hashable; build one with
    :func:`jaxgrid.ascii.from_ascii` or :func:`jaxgrid.compat.from_minigrid` rather than by hand.
    ``agent_dir=-1`` draws a random direction at each reset. The agent must start inside the
    grid on a cell it can stand on (empty, floor, goal, lava or an open door).
    ``mission_string`` is the level's mission (a converted env's own; ``None``: the default
    :attr:`MISSION`); its words outside :mod:`jaxgrid.mission`'s vocabulary encode as ``<unk>``
    and :meth:`mission_text` returns it verbatim.
    """

    layout: bytes = struct.field(pytree_node=False, default=b"")
    agent_start: tuple[int, int] = struct.field(pytree_node=False, default=(1, 1))
    agent_dir: int = struct.field(pytree_node=False, default=0)
    carrying: tuple[int, int, int] = struct.field(pytree_node=False, default=(1, 0, 0))
    mission_string: str | None = struct.field(pytree_node=False, default=None)

    def __post_init__(self):
        super().__post_init__()
        if len(self.layout) != self.width * self.height * 3:
            raise ValueError(
                f"FixedLevel.layout holds {len(self.layout)} bytes, expected width*height*3 = "
                f"{self.width * self.height * 3}"
            )
        x, y = self.agent_start
        if not (0 <= x < self.width and 0 <= y < self.height):
            raise ValueError(
                f"FixedLevel.agent_start {self.agent_start} is outside the "
                f"{self.width}x{self.height} grid"
            )
        i = (x * self.height + y) * 3
        kind, state = self.layout[i], self.layout[i + 2]
        if kind not in (EMPTY, FLOOR, GOAL, LAVA) and not (kind == DOOR and state == OPEN):
            what = OBJECT_NAMES[kind] if kind < len(OBJECT_NAMES) else f"object {kind}"
            raise ValueError(
                f"FixedLevel.agent_start {self.agent_start} is on a {what}; the agent stands on "
                "an empty cell, floor, goal, lava or an open door"
            )
        if self.agent_dir not in (-1, 0, 1, 2, 3):
            raise ValueError(f"FixedLevel.agent_dir must be 0..3 or -1, got {self.agent_dir!r}")

    def mission(self, state: State) -> jax.Array:
        return jnp.asarray(mission_words.encode(self.mission_text(state), strict=False))

    def mission_text(self, state: State) -> str:
        return self.MISSION if self.mission_string is None else self.mission_string

    def contents(self) -> Contents:
        """What the fixed grid and the carried object hold."""
        return Contents.of_grid(np.concatenate([self.grid.reshape(-1, 3), [self.carrying]]))

    @property
    def grid(self) -> np.ndarray:
        """The start grid as uint8 ``(W, H, 3)``."""
        return np.frombuffer(self.layout, np.uint8).reshape(self.width, self.height, 3)

    def generate(self, key: jax.Array) -> State:
        if self.agent_dir < 0:
            direction = jax.random.randint(key, (), 0, 4)
        else:
            direction = self.agent_dir
        state = self.init_state(self.grid, self.agent_start, direction, key)
        return state.replace(carrying=jnp.asarray(self.carrying, jnp.uint8))
