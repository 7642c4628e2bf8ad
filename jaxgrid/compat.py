"""Interoperability with Farama MiniGrid: convert a live MiniGrid env into ours."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxgrid.constants import COLOR_TO_IDX, EMPTY_CELL, OBJECT_TO_IDX
from jaxgrid.environment import Environment
from jaxgrid.levels import dynamic, keys, memory, missions, obstructed, rooms
from jaxgrid.levels.fixed import FixedLevel
from jaxgrid.types import State, TimeStep

SUPPORTED_TYPES = ("wall", "floor", "door", "key", "ball", "box", "goal", "lava")
# The native levels whose boxes keep what they hold (in ``state.extras``).
BOXES_HOLD = (obstructed.ObstructedMaze1D, obstructed.ObstructedMazeFull)


def _check_object(obj, where: str, boxes_hold: bool = False) -> None:
    if obj.type not in SUPPORTED_TYPES:
        raise ValueError(
            f"unsupported MiniGrid object {type(obj).__name__} (type {obj.type!r}) {where}; "
            f"supported types: {', '.join(SUPPORTED_TYPES)}"
        )
    inside = getattr(obj, "contains", None) if obj.type == "box" else None
    if inside is not None and boxes_hold:  # ObstructedMaze keeps what its boxes hold
        _check_object(inside, f"inside the box {where}")
    elif inside is not None:
        raise ValueError(
            f"a Box holding a {obj.contains.type} {where} is not supported here (only empty "
            "boxes are: opening one makes it vanish as in MiniGrid); the ObstructedMaze levels "
            "keep their boxes' contents when converted without base_step=True"
        )


def from_minigrid(
    mg_env, key: jax.Array | None = None, *, base_step: bool = False
) -> tuple[Environment, State, TimeStep]:
    """Convert a *reset* Farama MiniGrid env into ``(env, state, timestep)``.

    Takes the grid, agent pose, carried object, step count, ``max_steps``, view size and
    ``see_through_walls``; the returned ``state`` continues the MiniGrid episode where it
    stands. ``mg_env`` may be wrapped; its ``unwrapped`` is read. Unsupported objects and boxes
    with contents raise ``ValueError`` naming the object and its cell.

    For most levels ``env`` is a :class:`~jaxgrid.levels.FixedLevel`: it steps with
    ``MiniGridEnv.step``'s rules and ``env.reset`` returns the converted start (step count 0).

    ``UnlockEnv``, ``UnlockPickupEnv``, ``BlockedUnlockPickupEnv`` and ``KeyCorridorEnv`` (these
    exact classes; KeyCorridor with its default ``obj_type="ball"``) convert to the native level
    of the same family and configuration (:mod:`jaxgrid.levels.keys`): ``env.step`` applies the
    level's own success rule to the task object (``mg_env.door`` or ``mg_env.obj``, kept in
    ``state.extras``), and ``env.reset`` draws fresh layouts of the family, as MiniGrid's would.
    ``RedBlueDoorEnv`` (this exact class) likewise converts to
    :class:`~jaxgrid.levels.rooms.RedBlueDoors`, with the cells of ``mg_env.red_door`` and
    ``mg_env.blue_door`` in ``state.extras``. ``GoToDoorEnv``, ``GoToObjectEnv``, ``FetchEnv``
    and ``PutNearEnv`` (these exact classes) convert to their native levels
    (:mod:`jaxgrid.levels.missions`), with the attributes their ``step`` reads in
    ``state.extras``: ``target_pos`` and the target's colour (and type), Fetch's
    ``targetType``/``targetColor``, PutNear's object to move and ``target_pos``. ``MemoryEnv``
    converts to :class:`~jaxgrid.levels.memory.Memory` with ``success_pos`` and
    ``failure_pos``; ``DynamicObstaclesEnv`` to :class:`~jaxgrid.levels.dynamic.DynamicObstacles`
    with the cells of ``obstacles``, in order. ``ObstructedMaze_1Dlhb``, ``ObstructedMaze_Full``
    and ``ObstructedMaze_Full_V1`` convert to :mod:`jaxgrid.levels.obstructed`'s levels with
    ``obj`` (the blue ball) and what every box holds (``box.contains``, in the grid and in the
    agent's hands) in ``state.extras``; other levels refuse boxes that hold something.

    Any other class that overrides ``step`` (subclasses of the families above, ...) has rules
    of its own that are not reproduced, so it raises ``ValueError`` naming the class, unless
    ``base_step=True`` asks for its layout under ``MiniGridEnv.step``'s rules alone;
    ``base_step=True`` gives that ``FixedLevel`` for the families above too, except where a
    box holds something (its contents would be lost). An env that is not a MiniGrid env
    raises too.
    """
    from minigrid.minigrid_env import MiniGridEnv  # minigrid is needed here only

    env = getattr(mg_env, "unwrapped", mg_env)
    if not isinstance(env, MiniGridEnv):
        raise ValueError(
            f"from_minigrid needs a MiniGrid env (a minigrid.minigrid_env.MiniGridEnv, maybe "
            f"wrapped); got {type(env).__name__}, which is not a MiniGrid env"
        )
    cls = type(env)
    native = None if base_step else _native_family(env)
    if cls.step is not MiniGridEnv.step and not base_step and native is None:
        raise ValueError(
            f"{cls.__name__} overrides MiniGridEnv.step: its own step rules are not reproduced "
            "by the converted env (it steps with MiniGridEnv.step's rules only); pass "
            "base_step=True to convert its layout under those rules anyway"
        )
    if getattr(env, "grid", None) is None or getattr(env, "agent_pos", None) is None:
        raise ValueError("from_minigrid needs a MiniGrid env that has been reset")
    boxes_hold = native in BOXES_HOLD
    for i in range(env.grid.width):
        for j in range(env.grid.height):
            obj = env.grid.get(i, j)
            if obj is not None:
                _check_object(obj, f"at cell ({i}, {j})", boxes_hold)
    if env.carrying is not None:
        _check_object(env.carrying, "carried by the agent", boxes_hold)
    grid = env.grid.encode()
    carrying = tuple(int(c) for c in env.carrying.encode()) if env.carrying else tuple(EMPTY_CELL)
    pos = tuple(int(c) for c in env.agent_pos)
    if native is not None:
        return _convert_native(env, native, grid, carrying, pos, key)
    jenv = FixedLevel(
        **_settings(env),
        layout=np.ascontiguousarray(grid, np.uint8).tobytes(),
        agent_start=pos,
        agent_dir=int(env.agent_dir),
        carrying=carrying,
        mission_string=str(env.mission),
    )
    state = jenv.generate(jax.random.PRNGKey(0) if key is None else key)
    state = state.replace(step_count=jnp.asarray(env.step_count, jnp.int32))
    return jenv, state, jenv.first_timestep(state)


def _native_family(env):
    """The native level class for ``env``'s family, or None (see :func:`from_minigrid`)."""
    from minigrid.envs import (
        BlockedUnlockPickupEnv,
        DynamicObstaclesEnv,
        FetchEnv,
        GoToDoorEnv,
        GoToObjectEnv,
        KeyCorridorEnv,
        MemoryEnv,
        ObstructedMaze_1Dlhb,
        ObstructedMaze_Full,
        ObstructedMaze_Full_V1,
        PutNearEnv,
        RedBlueDoorEnv,
        UnlockEnv,
        UnlockPickupEnv,
    )

    families = {
        UnlockEnv: keys.Unlock,
        UnlockPickupEnv: keys.UnlockPickup,
        BlockedUnlockPickupEnv: keys.BlockedUnlockPickup,
        KeyCorridorEnv: keys.KeyCorridor,
        RedBlueDoorEnv: rooms.RedBlueDoors,
        GoToDoorEnv: missions.GoToDoor,
        GoToObjectEnv: missions.GoToObject,
        FetchEnv: missions.Fetch,
        PutNearEnv: missions.PutNear,
        MemoryEnv: memory.Memory,
        DynamicObstaclesEnv: dynamic.DynamicObstacles,
        ObstructedMaze_1Dlhb: obstructed.ObstructedMaze1D,
        ObstructedMaze_Full: obstructed.ObstructedMazeFull,
        ObstructedMaze_Full_V1: obstructed.ObstructedMazeFull,
    }
    native = families.get(type(env))
    if native is keys.KeyCorridor and env.obj_type != "ball":
        raise ValueError(
            f"KeyCorridorEnv with obj_type={env.obj_type!r} is not supported natively (only "
            "'ball'); pass base_step=True to convert its layout under MiniGridEnv.step's rules"
        )
    return native


def _settings(env) -> dict:
    """The settings every converted level takes from the MiniGrid env."""
    return dict(
        width=env.grid.width,
        height=env.grid.height,
        max_steps=int(env.max_steps),
        view_size=int(env.agent_view_size),
        see_through_walls=bool(env.see_through_walls),
    )


def _cell_of(env, obj, name: str) -> tuple[int, int]:
    """The cell of ``env``'s grid holding ``obj`` itself (an identity test, as MiniGrid's step
    rules read the object); ``ValueError`` naming the attribute if no cell does."""
    for index, held in enumerate(env.grid.grid):
        if held is obj:
            return index % env.grid.width, index // env.grid.width  # grid[j * width + i]
    raise ValueError(f"{type(env).__name__}.{name} is not in its grid")


def _first_cell_holding(env, kind: str, colour: str) -> tuple[int, int]:
    """The first cell of ``env``'s grid (MiniGrid's order) holding an object of ``kind`` and
    ``colour``; ``(-1, -1)`` if none does."""
    for index, held in enumerate(env.grid.grid):
        if held is not None and (held.type, held.color) == (kind, colour):
            return index % env.grid.width, index // env.grid.width  # grid[j * width + i]
    return -1, -1


def _mission_extras(env, native):
    """``state.extras`` of a mission level: what ``env.step`` reads, as its native level's."""

    def about(kind: str, colour: str, where) -> keys.Mission:
        return keys.mission(OBJECT_TO_IDX[kind], COLOR_TO_IDX[colour], tuple(where))

    if native is missions.GoToDoor:
        return about("door", env.target_color, env.target_pos)
    if native is missions.GoToObject:
        return about(env.targetType, env.target_color, env.target_pos)
    if native is missions.Fetch:  # FetchEnv keeps the target's type and colour only
        where = _first_cell_holding(env, env.targetType, env.targetColor)
        target = about(env.targetType, env.targetColor, where)
        return missions.FetchMission(**vars(target), phrasing=_fetch_phrasing(env))
    return missions.PutNearMission(
        move=about(env.move_type, env.moveColor, env.move_pos),
        target=about(env.target_type, env.target_color, env.target_pos),
    )


def _fetch_phrasing(env) -> jax.Array:
    """Which of ``FETCH_PHRASINGS`` leads ``env.mission``, as an int32 index. The native
    mission spells the target from the task the step reads (``targetType``/``targetColor``)."""
    leads = [lead for lead in missions.FETCH_PHRASINGS if env.mission.startswith(lead + " ")]
    if not leads:
        raise ValueError(f"FetchEnv.mission {env.mission!r} starts with none of its phrasings")
    return jnp.int32(missions.FETCH_PHRASINGS.index(leads[0]))


def _obstructed(env, native):
    """An ObstructedMaze level and its :class:`~jaxgrid.levels.obstructed.HiddenKeys`: the blue
    ball the step rule tests (``env.obj``) and what each box holds, in the grid and in hand."""
    from minigrid.envs import ObstructedMaze_Full_V1

    settings = dict(_settings(env), key_in_box=bool(env.key_in_box), blocked=bool(env.blocked))
    if native is obstructed.ObstructedMazeFull:
        settings.update(
            num_quarters=int(env.num_quarters),
            agent_room=tuple(int(c) for c in env.agent_room),
            keys_after_doors=isinstance(env, ObstructedMaze_Full_V1),
        )
    jenv = native(**settings)

    def held(obj) -> np.ndarray:  # the encoding of what a box holds (empty: EMPTY_CELL)
        inside = getattr(obj, "contains", None) if obj is not None else None
        return np.asarray(inside.encode() if inside is not None else EMPTY_CELL, np.uint8)

    contents = np.zeros((env.grid.width, env.grid.height, 3), np.uint8)
    for i in range(env.grid.width):
        for j in range(env.grid.height):
            contents[i, j] = held(env.grid.get(i, j))
    target = env.obj
    where = target.cur_pos if target.cur_pos is not None else (-1, -1)
    task = keys.mission(OBJECT_TO_IDX[target.type], COLOR_TO_IDX[target.color], where)
    extras = obstructed.HiddenKeys(
        **vars(task), contents=jnp.asarray(contents), carried=jnp.asarray(held(env.carrying))
    )
    return jenv, extras


def _convert_native(env, native, grid, carrying, pos, key):
    """``(native env, state, timestep)`` continuing ``env``'s episode under its own rules."""
    if native is missions.GoToDoor:
        jenv = native(**_settings(env))
        extras = _mission_extras(env, native)
    elif native in (missions.GoToObject, missions.Fetch, missions.PutNear):
        jenv = native(**_settings(env), num_objs=int(env.numObjs))
        extras = _mission_extras(env, native)
    elif native is dynamic.DynamicObstacles:
        start = env.agent_start_pos
        jenv = native(
            **_settings(env),
            n_obstacles=len(env.obstacles),
            agent_start=None if start is None else tuple(int(c) for c in start),
            agent_start_dir=int(env.agent_start_dir),
        )
        cells = [_cell_of(env, ball, f"obstacles[{i}]") for i, ball in enumerate(env.obstacles)]
        extras = jnp.asarray(cells, jnp.int32).reshape(len(cells), 2)
    elif native is memory.Memory:
        jenv = native(**_settings(env), random_length=bool(env.random_length))
        extras = memory.MemoryTask(
            success=jnp.asarray(env.success_pos, jnp.int32),
            failure=jnp.asarray(env.failure_pos, jnp.int32),
        )
    elif native in BOXES_HOLD:
        jenv, extras = _obstructed(env, native)
    elif native is rooms.RedBlueDoors:
        jenv = native(**_settings(env))
        extras = rooms.DoorPair(
            red=jnp.asarray(_cell_of(env, env.red_door, "red_door"), jnp.int32),
            blue=jnp.asarray(_cell_of(env, env.blue_door, "blue_door"), jnp.int32),
        )
    else:
        settings = dict(_settings(env), room_size=int(env.room_size))
        if native is keys.KeyCorridor:
            settings.update(num_rows=int(env.num_rows), num_cols=int(env.num_cols))
        elif (env.num_rows, env.num_cols) != (1, 2):
            raise ValueError(f"{type(env).__name__} must have one row of two rooms")
        jenv = native(**settings)
        target = env.door if native is keys.Unlock else env.obj  # what the step rule tests
        where = target.cur_pos if target.cur_pos is not None else (-1, -1)
        extras = keys.mission(OBJECT_TO_IDX[target.type], COLOR_TO_IDX[target.color], where)
    state = jenv.init_state(
        grid, pos, int(env.agent_dir), jax.random.PRNGKey(0) if key is None else key, extras
    )
    state = state.replace(
        carrying=jnp.asarray(carrying, jnp.uint8),
        step_count=jnp.asarray(env.step_count, jnp.int32),
    )
    return jenv, state, jenv.first_timestep(state)
