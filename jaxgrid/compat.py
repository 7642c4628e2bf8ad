"""Interoperability with Farama MiniGrid: convert a live MiniGrid env into ours."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrid.constants import EMPTY_CELL
from jaxgrid.levels.fixed import FixedLevel
from jaxgrid.types import State, TimeStep

SUPPORTED_TYPES = ("wall", "floor", "door", "key", "ball", "box", "goal", "lava")


def _check_object(obj, where: str) -> None:
    if obj.type not in SUPPORTED_TYPES:
        raise ValueError(
            f"unsupported MiniGrid object {type(obj).__name__} (type {obj.type!r}) {where}; "
            f"supported types: {', '.join(SUPPORTED_TYPES)}"
        )
    if obj.type == "box" and getattr(obj, "contains", None) is not None:
        raise ValueError(
            f"a Box holding a {obj.contains.type} {where} is not supported "
            "(only empty boxes are; opening one makes it vanish as in MiniGrid)"
        )


def from_minigrid(
    mg_env, key: jax.Array | None = None, *, base_step: bool = False
) -> tuple[FixedLevel, State, TimeStep]:
    """Convert a *reset* Farama MiniGrid env into ``(env, state, timestep)``.

    Takes the grid, agent pose, carried object, step count, ``max_steps``, view size and
    ``see_through_walls``. ``env.reset`` later returns the converted start (step count 0); the
    returned ``state`` continues the MiniGrid episode where it stands. ``mg_env`` may be wrapped;
    its ``unwrapped`` is read. Unsupported objects and boxes with contents raise ``ValueError``
    naming the object and its cell.

    The converted env steps with ``MiniGridEnv.step``'s rules. A level whose class overrides
    ``step`` (Unlock ends on opening the door, DynamicObstacles moves its balls, Memory,
    KeyCorridor, RedBlueDoors, ...) has rules of its own that are not reproduced, so it raises
    ``ValueError`` naming the class, unless ``base_step=True`` asks for its layout under
    ``MiniGridEnv.step``'s rules alone. An env that is not a MiniGrid env raises too.
    """
    from minigrid.minigrid_env import MiniGridEnv  # minigrid is needed here only

    env = getattr(mg_env, "unwrapped", mg_env)
    if not isinstance(env, MiniGridEnv):
        raise ValueError(
            f"from_minigrid needs a MiniGrid env (a minigrid.minigrid_env.MiniGridEnv, maybe "
            f"wrapped); got {type(env).__name__}, which is not a MiniGrid env"
        )
    cls = type(env)
    if cls.step is not MiniGridEnv.step and not base_step:
        raise ValueError(
            f"{cls.__name__} overrides MiniGridEnv.step: its own step rules are not reproduced "
            "by the converted env (it steps with MiniGridEnv.step's rules only); pass "
            "base_step=True to convert its layout under those rules anyway"
        )
    if getattr(env, "grid", None) is None or getattr(env, "agent_pos", None) is None:
        raise ValueError("from_minigrid needs a MiniGrid env that has been reset")
    for i in range(env.grid.width):
        for j in range(env.grid.height):
            obj = env.grid.get(i, j)
            if obj is not None:
                _check_object(obj, f"at cell ({i}, {j})")
    if env.carrying is not None:
        _check_object(env.carrying, "carried by the agent")
    grid = env.grid.encode()
    carrying = tuple(int(c) for c in env.carrying.encode()) if env.carrying else tuple(EMPTY_CELL)
    pos = tuple(int(c) for c in env.agent_pos)
    jenv = FixedLevel(
        width=env.grid.width,
        height=env.grid.height,
        max_steps=int(env.max_steps),
        view_size=int(env.agent_view_size),
        see_through_walls=bool(env.see_through_walls),
        layout=np.ascontiguousarray(grid, np.uint8).tobytes(),
        agent_start=pos,
        agent_dir=int(env.agent_dir),
        carrying=carrying,
    )
    state = jenv.generate(jax.random.PRNGKey(0) if key is None else key)
    state = state.replace(step_count=jnp.asarray(env.step_count, jnp.int32))
    return jenv, state, jenv.first_timestep(state)
