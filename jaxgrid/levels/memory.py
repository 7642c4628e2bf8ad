"""MiniGrid's Memory levels, generated natively, with their own step rule.

``generate`` mirrors ``MemoryEnv._gen_grid``; the comments quote the MiniGrid call each line
reproduces. Every draw is a plain uniform one (the hallway's end when ``random_length``, the
agent's column, the start room's object, the order of the two objects at the hallway's end),
so there is no rejection to replace.

``MemoryEnv`` overrides ``step``, here alike (:meth:`Memory.step`): ``pickup`` acts as
``toggle``; after ``MiniGridEnv.step``, standing on the cell next to the object that matches
the start room's pays ``1 - 0.9 * step_count / max_steps`` and terminates, standing next to
the other object terminates with reward 0. As in MiniGrid, the rule applies again on any
step taken after termination. :data:`IDS` maps MiniGrid's ids, with its per-id defaults,
to factories.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from jaxgrid import grid as G
from jaxgrid.constants import BALL, EMPTY_CELL, GREEN, KEY, PICKUP, TOGGLE, WALL_CELL
from jaxgrid.contents import Contents
from jaxgrid.dynamics import transition
from jaxgrid.environment import Environment, check_action
from jaxgrid.types import State, TimeStep


@struct.dataclass
class MemoryTask:
    """``success_pos`` and ``failure_pos`` of ``MemoryEnv``, int32 ``(2,)`` each."""

    success: jax.Array
    failure: jax.Array


class Memory(Environment):
    """``MemoryEnv``: remember the object in the start room, walk down the hallway and stand
    next to the matching one of the two objects at its end.

    Layout (height ``h``, middle row ``m = h // 2``): a start room of columns 1-3 between rows
    ``m - 2`` and ``m + 2``, a hallway along row ``m`` up to column ``end`` (``width - 3``, or
    uniform in ``4 .. width - 3`` when ``random_length``), a vertical hallway at column
    ``end + 1`` with a green key or ball at rows ``m - 2`` and ``m + 2`` (a uniform order),
    and a green key or ball (uniform) at ``(1, m - 1)``. The agent starts on row ``m`` at a
    uniform column ``1 .. end``, facing right. ``state.extras`` is a :class:`MemoryTask`.
    MiniGrid builds square sizes only; here the height must be odd (the hallway is the middle
    row) and both sides at least 7.
    """

    random_length: bool = struct.field(pytree_node=False, default=False)

    MISSION = "go to the matching object at the end of the hallway"

    def __post_init__(self):
        super().__post_init__()
        if self.height % 2 == 0:
            raise ValueError(
                f"Memory.height must be odd (MemoryEnv asserts height % 2 == 1: the hallway "
                f"is the middle row), got {self.height}"
            )

    def min_size(self):
        return 7, 7, "a start room of three columns and the objects inside the outer walls"

    CONTENTS = Contents(key={"green"}, ball={"green"})

    def layout(self, end: jax.Array) -> jax.Array:
        """The walls, uint8 ``(W, H, 3)``, for the hallway ending at column ``end``."""
        w, h = self.width, self.height
        xs, ys = G.coords(w, h)
        upper, lower, mid = h // 2 - 2, h // 2 + 2, h // 2  # upper_room_wall, lower_room_wall
        inner = (ys == upper + 1) | (ys == lower - 1)
        wall = (xs == 0) | (xs == w - 1) | (ys == 0) | (ys == h - 1)
        wall |= ((ys == upper) | (ys == lower)) & (xs >= 1) & (xs <= 4)  # start room
        wall |= (xs == 4) & inner
        wall |= (xs >= 5) & (xs < end) & inner  # horizontal hallway
        wall |= ((xs == end) & (ys != mid)) | (xs == end + 2)  # vertical hallway
        return jnp.where(wall[..., None], jnp.asarray(WALL_CELL), jnp.asarray(EMPTY_CELL))

    def generate(self, key: jax.Array) -> State:
        w, h = self.width, self.height
        mid = h // 2
        u = jax.random.uniform(key, (4,))
        if self.random_length:
            end = G.randint(u[0], 4, w - 2)  # hallway_end = _rand_int(4, width - 2)
        else:
            end = jnp.int32(w - 3)
        grid = self.layout(end)
        # agent_pos = (_rand_int(1, hallway_end + 1), height // 2); agent_dir = 0
        agent = jnp.stack([G.randint(u[1], 1, end + 1), jnp.int32(mid)])
        # start_room_obj = _rand_elem([Key, Ball]); other_objs = _rand_elem([[Ball, Key],
        # [Key, Ball]]): the first end object is a key in the second case
        start = jnp.where(G.randint(u[2], 0, 2) == 0, KEY, BALL)
        first = jnp.where(G.randint(u[3], 0, 2) == 0, BALL, KEY)
        second = KEY + BALL - first
        grid = G.put(grid, (1, mid - 1), G.cell(start, GREEN))
        pos0 = jnp.stack([end + 1, jnp.int32(mid - 2)])
        pos1 = jnp.stack([end + 1, jnp.int32(mid + 2)])
        grid = G.put(G.put(grid, pos0, G.cell(first, GREEN)), pos1, G.cell(second, GREEN))
        # success next to the end object of the start room's type, failure next to the other
        up, down = pos0 + jnp.array([0, 1]), pos1 - jnp.array([0, 1])
        matches_first = start == first
        task = MemoryTask(
            success=jnp.where(matches_first, up, down).astype(jnp.int32),
            failure=jnp.where(matches_first, down, up).astype(jnp.int32),
        )
        return self.init_state(grid, agent, 0, key, task)

    def step(self, state: State, action: jax.Array) -> tuple[State, TimeStep]:
        """``MemoryEnv.step``: pickup acts as toggle, then the success and failure cells."""
        check_action(action)
        action = jnp.asarray(action, jnp.int32)
        action = jnp.where(action == PICKUP, TOGGLE, action)  # if action == pickup: toggle
        state, reward, terminated, truncated = transition(state, action, self.max_steps)
        task = state.extras
        success = jnp.all(state.agent_pos == task.success)
        failure = jnp.all(state.agent_pos == task.failure)
        paid = 1.0 - 0.9 * (state.step_count.astype(jnp.float32) / self.max_steps)
        reward = jnp.where(success, paid, jnp.where(failure, 0.0, reward)).astype(jnp.float32)
        terminated = terminated | success | failure
        return state, self.make_timestep(state, reward, terminated, truncated)


def _memory(size: int, random_length: bool = False) -> Callable[[], Environment]:
    # MemoryEnv(size, random_length): max_steps 5 * size**2, see_through_walls=False.
    return lambda: Memory(
        width=size, height=size, max_steps=5 * size**2, random_length=random_length
    )


IDS: dict[str, Callable[[], Environment]] = {
    "MiniGrid-MemoryS17Random-v0": _memory(17, True),
    "MiniGrid-MemoryS13Random-v0": _memory(13, True),
    "MiniGrid-MemoryS13-v0": _memory(13),
    "MiniGrid-MemoryS11-v0": _memory(11),
    "MiniGrid-MemoryS9-v0": _memory(9),
    "MiniGrid-MemoryS7-v0": _memory(7),
}
