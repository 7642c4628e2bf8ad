"""Every level's declared contents against what its resets hold, and the Contents checks.

A level declares what its episodes can hold (``Environment.contents``); here many sampled
resets of every registered id (one id per level class in the default run, every id with
``-m slow``) must hold nothing undeclared, and every declared kind and colour must turn up
(the declaration is exact, so a sentence is refused only for what the level never holds).
ObstructedMaze's keys hidden in boxes count (``HiddenKeys.contents``).
"""

from __future__ import annotations

import functools

import jax
import numpy as np
import pytest
from helpers.xla import CHEAP

import jaxgrid
from jaxgrid import language as L
from jaxgrid.contents import ALL_COLOURS, NOTHING, Contents
from jaxgrid.levels.obstructed import HiddenKeys

IDS = jaxgrid.registered_ids()
# One id per level class for the default run (the first of each), HazardRooms' slow reset apart.
ONE_PER_CLASS = set({type(jaxgrid.make(i)): i for i in reversed(IDS)}.values()) - {"HazardRooms-v0"}


@functools.cache
def _seen(env_id: str, n: int) -> Contents:
    env = jaxgrid.make(env_id)
    reset = jax.jit(jax.vmap(env.reset), compiler_options=CHEAP)
    states, _ = reset(jax.random.split(jax.random.key(1), n))
    cells = [np.asarray(states.grid).reshape(-1, 3)]
    if isinstance(states.extras, HiddenKeys):  # keys inside boxes
        cells.append(np.asarray(states.extras.contents).reshape(-1, 3))
    return Contents.of_grid(np.concatenate(cells))


@pytest.mark.parametrize(
    "env_id",
    [pytest.param(i, marks=() if i in ONE_PER_CLASS else pytest.mark.slow) for i in IDS],
)
def test_declared_contents_are_what_the_resets_hold(env_id):
    declared = jaxgrid.make(env_id).contents()
    seen = _seen(env_id, 256)
    assert seen <= declared, f"undeclared: {seen.describe()} vs {declared.describe()}"
    assert declared <= seen, f"never seen: {declared.describe()} vs {seen.describe()}"


def test_levels_without_a_nameable_thing_declare_nothing():
    for env_id in ("MiniGrid-Empty-5x5-v0", "MiniGrid-FourRooms-v0",
                   "MiniGrid-SimpleCrossingS9N1-v0"):  # fmt: skip
        assert jaxgrid.make(env_id).contents() == NOTHING


def test_check_names_the_missing_word():
    doorkey = Contents(door={"yellow"}, key={"yellow"})
    with pytest.raises(ValueError, match=r"never holds lava \(the word 'lava'\)"):
        doorkey.check(L.parse("avoid lava"), "DoorKey")
    with pytest.raises(ValueError, match=r"never holds a red door \(the word 'red'\)"):
        doorkey.check(L.parse("do not use the red door"), "DoorKey")
    with pytest.raises(ValueError, match=r"never holds a ball \(the word 'ball'\)"):
        doorkey.check(L.parse("after you pick up the ball do not use the yellow door"), "DoorKey")
    with pytest.raises(ValueError, match=r"never holds a blue floor \(the word 'floor'\)"):
        doorkey.check(L.parse("avoid water"), "DoorKey")
    doorkey.check(L.parse("after you pick up the key do not use the yellow door"), "DoorKey")
    assert doorkey.allows(L.parse("use the yellow door at most twice"))
    assert not doorkey.allows(L.parse("avoid the yellow door and avoid lava"))


def test_contents_refuse_bad_declarations_and_compare():
    with pytest.raises(ValueError, match="unknown colour 'pink'"):
        Contents(door={"pink"})
    with pytest.raises(ValueError, match="takes colour names"):
        Contents(key="red")
    every = Contents(door=ALL_COLOURS, lava=True)
    assert Contents(lava=True) <= every and not every <= Contents(lava=True)
    assert (Contents(lava=True) | Contents(door={"red"})) == Contents(door={"red"}, lava=True)
    assert NOTHING.empty and NOTHING.describe() == "nothing a constraint can name"
    objects = Contents(key=ALL_COLOURS, ball={"red"})  # triggers only: no clause to say
    assert not objects.empty and not objects.constrainable
    assert Contents(floor={"blue"}).constrainable
