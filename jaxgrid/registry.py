"""``make(id)``: environment ids, MiniGrid's own names for the classic levels."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

from jaxgrid.constrained import check_lava, constrain
from jaxgrid.environment import Environment
from jaxgrid.hazard import HazardRooms
from jaxgrid.levels import (
    DoorKey,
    Empty,
    LavaGap,
    dynamic,
    keys,
    memory,
    missions,
    navigation,
    obstructed,
    playground,
    rooms,
)
from jaxgrid.scenarios import ThreeRoomsKey, TwoRooms


def _empty(size: int, random_start: bool = False) -> Callable[[], Environment]:
    # EmptyEnv: max_steps 4 * size**2, see_through_walls=True.
    return lambda: Empty(
        width=size,
        height=size,
        max_steps=4 * size**2,
        see_through_walls=True,
        random_start=random_start,
    )


def _doorkey(size: int) -> Callable[[], Environment]:
    # DoorKeyEnv: max_steps 10 * size**2, see_through_walls=False.
    return lambda: DoorKey(width=size, height=size, max_steps=10 * size**2)


def _lavagap(size: int) -> Callable[[], Environment]:
    # LavaGapEnv: max_steps 4 * size**2, see_through_walls=False.
    return lambda: LavaGap(width=size, height=size, max_steps=4 * size**2)


def _scenarios() -> dict[str, Callable[[], Environment]]:
    # The paper's scenarios: 5x5 view, see_through_walls=False.
    two = dict(width=9, height=7, max_steps=100, view_size=5)
    return {
        "TwoRooms-v0": lambda: TwoRooms(**two),
        "TwoRoomsLava-v0": lambda: TwoRooms(**two, has_lava=True),
        "ThreeRoomsKey-v0": lambda: ThreeRoomsKey(width=13, height=7, max_steps=150, view_size=5),
        # Beyond the paper: rich constraints, MiniGrid's default 7x7 view.
        "HazardRooms-v0": lambda: HazardRooms(width=13, height=13, max_steps=150),
    }


_BUILTIN: dict[str, Callable[[], Environment]] = {
    **{f"MiniGrid-Empty-{n}x{n}-v0": _empty(n) for n in (5, 6, 8, 16)},
    **{f"MiniGrid-Empty-Random-{n}x{n}-v0": _empty(n, True) for n in (5, 6)},
    **{f"MiniGrid-DoorKey-{n}x{n}-v0": _doorkey(n) for n in (5, 6, 8, 16)},
    **{f"MiniGrid-LavaGapS{n}-v0": _lavagap(n) for n in (5, 6, 7)},
    **navigation.IDS,
    **keys.IDS,
    **rooms.IDS,
    **missions.IDS,
    **memory.IDS,
    **playground.IDS,
    **dynamic.IDS,
    **obstructed.IDS,
    **_scenarios(),
}
_USER: dict[str, Callable[[], Environment]] = {}


def register(env_id: str, factory: Callable[[], Environment], *, overwrite: bool = False):
    """Register ``factory`` (a zero-argument callable returning an env) under ``env_id``."""
    if not overwrite and env_id in registered_ids():
        raise ValueError(f"environment id {env_id!r} is already registered")
    _USER[env_id] = factory


def unregister(env_id: str) -> None:
    """Remove an id added with :func:`register`; built-in ids cannot be removed.

    An id that is not registered, or is built in, raises ``ValueError`` naming it.
    """
    if env_id in _USER:
        del _USER[env_id]
    elif env_id in _BUILTIN:
        raise ValueError(f"environment id {env_id!r} is built in and cannot be unregistered")
    else:
        raise ValueError(f"environment id {env_id!r} is not registered")


def _table() -> dict[str, Callable[[], Environment]]:
    table = dict(_BUILTIN)
    table.update(_USER)
    return table


def registered_ids() -> list[str]:
    """All ids ``make`` accepts, sorted."""
    return sorted(_table())


def make(
    env_id: str, *, constraint=None, constraints=None, weights=None, lava=None, **overrides
) -> Environment:
    """Build the environment registered as ``env_id``.

    ``overrides`` replace configuration fields, e.g. ``make("MiniGrid-DoorKey-8x8-v0",
    view_size=5, max_steps=100)``. An unknown id or field raises ``ValueError``.

    A constraint makes the level a constrained environment
    (:func:`jaxgrid.constrained.constrain`): ``constraint`` is one sentence, ``constraints``
    several drawn one per episode (by ``weights``, uniformly by default) or a sentence table
    (:data:`jaxgrid.sentences.LEVELS`: its rows naming only what the level holds), and
    ``lava`` is ``"lethal"`` (MiniGrid's, the default) or ``"cost"`` (lava costs what the
    constraint says and ends no episode). Without a constraint the level is unchanged; a bad
    value, or a sentence naming what the level never holds, raises ``ValueError`` naming it
    before anything compiles.
    """
    if lava is not None:
        check_lava(lava)
    if constraint is None and constraints is None:
        for option, value in (("weights", weights), ("lava", lava)):
            if value is not None and (option, value) != ("lava", "lethal"):
                raise ValueError(
                    f"{option}={value!r} needs a constraint (constraint= or constraints=)"
                )
    table = _table()
    if env_id not in table:
        raise ValueError(
            f"unknown environment id {env_id!r}; registered ids: {', '.join(sorted(table))}"
        )
    env = table[env_id]()
    if overrides:
        fields = {f.name for f in dataclasses.fields(env)}
        unknown = sorted(set(overrides) - fields)
        if unknown:
            raise ValueError(
                f"{env_id} has no setting {unknown[0]!r}; settings: {', '.join(sorted(fields))}"
            )
        env = env.replace(**overrides)
    if constraint is None and constraints is None:
        return env
    return constrain(
        env, constraint=constraint, constraints=constraints, weights=weights, lava=lava,
        name=env_id,
    )  # fmt: skip
