"""Step-by-step equality with Farama MiniGrid 3.2.0 (the reference implementation).

For each level, MiniGrid is reset with many seeds, converted with ``jaxgrid.compat.from_minigrid``
and both are stepped with the same biased random actions; after every step we compare the
observation image, direction, reward (within 1e-6), terminated, truncated, the full grid
encoding, the agent's position and the carried object, up to MiniGrid's episode end. See
``tests/helpers/minigrid_reference.py`` for the machinery (one jitted ``vmap(lax.scan)`` per
level).

Levels whose ``step`` overrides ``MiniGridEnv.step`` (KeyCorridor, Unlock, UnlockPickup,
BlockedUnlockPickup, ObstructedMaze, RedBlueDoors) only add a level-specific reward/termination
on top of it; here they are converted with ``base_step=True`` and MiniGrid steps them with
``MiniGridEnv.step`` itself, so their layouts exercise the core dynamics (ObstructedMaze-1Dl
has no box, whose contents ``base_step`` would drop). Each also has a native level with its
own rules, which ``from_minigrid`` returns by default; ``test_key_levels.py``,
``test_obstructed_maze.py`` and the family test files step those against MiniGrid's own
``step``.

Natively generated levels step like MiniGrid too: our resets, copied into MiniGrid, for a few
levels in the default run and for every registered MiniGrid id with ``-m slow`` (the own-rule
levels there under ``MiniGridEnv.step``'s rules).

With a constraint on (a level made with ``constraints=jaxgrid.sentences.LEVELS``: each
episode a row of the levels' table it can hold), every level that can hold one still steps
like MiniGrid: the
converted levels (the own-rule ones converted to their native level, under their own rules)
and the native resets, a few levels in the default run and all of them with ``-m slow``.
"""

from __future__ import annotations

import functools
import zlib

import jax
import numpy as np
import pytest
from helpers import minigrid_reference as R
from helpers.xla import CHEAP
from minigrid.core.world_object import Ball, Box, Key

import jaxgrid
from jaxgrid.compat import from_minigrid
from jaxgrid.constrained import ConstrainedLevel
from jaxgrid.environment import Environment
from jaxgrid.sentences import LEVELS as LEVEL_TABLE

SEEDS = 32  # per level in the default run
SLOW_SEEDS = 200
MAX_T = 300  # steps per episode at most (episodes end earlier at max_steps / goal / lava)

# (label, MiniGrid id, gym.make kwargs, use MiniGridEnv.step itself)
LEVELS = [
    ("DoorKey-5x5", "MiniGrid-DoorKey-5x5-v0", {}, False),
    ("DoorKey-8x8", "MiniGrid-DoorKey-8x8-v0", {}, False),
    (
        "DoorKey-8x8-view3",
        "MiniGrid-DoorKey-8x8-v0",
        {"agent_view_size": 3, "max_steps": 150},
        False,
    ),
    (
        "DoorKey-8x8-view5",
        "MiniGrid-DoorKey-8x8-v0",
        {"agent_view_size": 5, "max_steps": 150},
        False,
    ),
    (
        "DoorKey-8x8-seethrough",
        "MiniGrid-DoorKey-8x8-v0",
        {"see_through_walls": True, "max_steps": 150},
        False,
    ),
    (
        "DoorKey-16x16-view11",
        "MiniGrid-DoorKey-16x16-v0",
        {"agent_view_size": 11, "max_steps": 150},
        False,
    ),  # no lookup table above view 9
    ("LavaGapS5", "MiniGrid-LavaGapS5-v0", {}, False),
    ("LavaGapS7", "MiniGrid-LavaGapS7-v0", {}, False),
    ("MultiRoom-N4-S5", "MiniGrid-MultiRoom-N4-S5-v0", {}, False),
    ("MultiRoom-N2-S4", "MiniGrid-MultiRoom-N2-S4-v0", {}, False),
    ("FourRooms", "MiniGrid-FourRooms-v0", {}, False),
    ("LavaCrossingS9N2", "MiniGrid-LavaCrossingS9N2-v0", {}, False),
    ("SimpleCrossingS9N1", "MiniGrid-SimpleCrossingS9N1-v0", {}, False),
    ("LockedRoom", "MiniGrid-LockedRoom-v0", {}, False),
    ("Empty-8x8", "MiniGrid-Empty-8x8-v0", {}, False),  # see_through_walls=True
    ("Empty-Random-5x5", "MiniGrid-Empty-Random-5x5-v0", {}, False),
    ("DistShift1", "MiniGrid-DistShift1-v0", {}, False),  # see_through_walls=True
    ("Playground", "MiniGrid-Playground-v0", {}, False),  # empty boxes, keys, balls, doors
    ("KeyCorridorS3R3", "MiniGrid-KeyCorridorS3R3-v0", {}, True),
    ("BlockedUnlockPickup", "MiniGrid-BlockedUnlockPickup-v0", {}, True),
    ("UnlockPickup", "MiniGrid-UnlockPickup-v0", {"max_steps": 150}, True),
    ("ObstructedMaze-1Dl", "MiniGrid-ObstructedMaze-1Dl-v0", {"max_steps": 150}, True),
    ("RedBlueDoors-6x6", "MiniGrid-RedBlueDoors-6x6-v0", {"max_steps": 150}, True),
]
# The default run steps a representative level of each kind (keys and locked doors, a 3x3 view,
# see-through walls, lava, several rooms, boxes and balls, a level with its own step, a random
# start); the others run with ``-m slow``, as do many more seeds of every level.
DEFAULT_LEVELS = {
    "DoorKey-5x5",
    "DoorKey-8x8-view3",
    "DistShift1",
    "LavaGapS7",
    "MultiRoom-N2-S4",
    "Playground",
    "ObstructedMaze-1Dl",
    "Empty-Random-5x5",
}
SLOW_LEVELS = LEVELS + [
    ("DoorKey-16x16", "MiniGrid-DoorKey-16x16-v0", {}, False),
    ("DoorKey-6x6-view9", "MiniGrid-DoorKey-6x6-v0", {"agent_view_size": 9}, False),
    ("DoorKey-8x8-view13", "MiniGrid-DoorKey-8x8-v0", {"agent_view_size": 13}, False),
    ("LavaCrossingS11N5", "MiniGrid-LavaCrossingS11N5-v0", {}, False),
    ("SimpleCrossingS11N5", "MiniGrid-SimpleCrossingS11N5-v0", {}, False),
    ("MultiRoom-N6", "MiniGrid-MultiRoom-N6-v0", {}, False),
    ("DistShift2", "MiniGrid-DistShift2-v0", {}, False),
    ("Empty-16x16", "MiniGrid-Empty-16x16-v0", {}, False),
    ("KeyCorridorS6R3", "MiniGrid-KeyCorridorS6R3-v0", {}, True),
    ("Unlock", "MiniGrid-Unlock-v0", {}, True),
    ("RedBlueDoors-8x8", "MiniGrid-RedBlueDoors-8x8-v0", {}, True),
]


def _constrained(env_id):
    """A constrained level of ``env_id`` with a configuration's settings, for ``constrained=``."""
    settings = ("max_steps", "view_size", "see_through_walls")
    return lambda cfg: jaxgrid.make(
        env_id, constraints=LEVEL_TABLE, **{k: getattr(cfg, k) for k in settings}
    )


def _holds_a_target(env_id) -> bool:
    return jaxgrid.make(env_id).contents().constrainable


def _run(env_id, kwargs, base_step, seeds, action_seed=0, **kw):
    mg = R.make_reference(env_id, **kwargs)
    label = f"{env_id} {kwargs}" + (" constrained" if kw.get("constrained") else "")
    return R.differential_run(
        mg,
        seeds,
        min(mg.max_steps, MAX_T),
        label=label,
        base_step=base_step,
        action_seed=zlib.crc32(label.encode()) + action_seed,
        **kw,  # own actions per variant
    )


@functools.cache
def _default_episodes(label):
    """The recorded episodes of level ``label``'s default run (once per test process)."""
    _, env_id, kwargs, base_step = next(lv for lv in LEVELS if lv[0] == label)
    return _run(env_id, kwargs, base_step, range(SEEDS))


@pytest.mark.parametrize(
    "label",
    [
        pytest.param(lv[0], id=lv[0], marks=() if lv[0] in DEFAULT_LEVELS else pytest.mark.slow)
        for lv in LEVELS
    ],
)
def test_converted_levels_step_like_minigrid(label):
    episodes = _default_episodes(label)
    assert len(episodes) == SEEDS and sum(ep.length for ep in episodes) >= SEEDS


@pytest.mark.slow
@pytest.mark.parametrize(
    "env_id, kwargs, base_step", [lv[1:] for lv in SLOW_LEVELS], ids=[lv[0] for lv in SLOW_LEVELS]
)
def test_converted_levels_step_like_minigrid_many_seeds(env_id, kwargs, base_step):
    # Different seeds from the default run, a different action stream, and grid.encode() after
    # every step (no assumption about which actions leave the grid alone).
    _run(
        env_id,
        kwargs,
        base_step,
        range(1000, 1000 + SLOW_SEEDS),
        action_seed=1,
        encode_every_step=True,
    )


# With a constraint on: the levels that can hold one (own-rule levels under their own rules).
CONSTRAINED_DEFAULT = {"DoorKey-5x5", "LavaGapS7", "Playground", "RedBlueDoors-6x6"}
CONSTRAINED_LEVELS = [lv for lv in SLOW_LEVELS if _holds_a_target(lv[1])]


@pytest.mark.parametrize(
    "env_id, kwargs",
    [pytest.param(*lv[1:3], id=lv[0],
                  marks=() if lv[0] in CONSTRAINED_DEFAULT else pytest.mark.slow)
     for lv in CONSTRAINED_LEVELS],
)  # fmt: skip
def test_converted_levels_step_like_minigrid_with_a_constraint(env_id, kwargs):
    seeds = range(2000, 2000 + SEEDS)
    episodes = _run(env_id, kwargs, False, seeds, action_seed=2, constrained=_constrained(env_id))
    assert len(episodes) == SEEDS


def test_differential_run_exercises_the_dynamics():
    """The random-action runs above are not vacuous: goals, lava, doors, boxes, hands all move."""
    totals = {}
    for label in ("DoorKey-5x5", "LavaGapS7", "Playground"):
        for k, v in R.coverage(_default_episodes(label)).items():
            totals[k] = totals.get(k, 0) + v
    for event in ("goal", "lava", "truncated", "pickups", "drops", "unlocks", "box_opened"):
        assert totals[event] > 0, (event, totals)


def test_goal_on_the_last_step_is_terminated_and_truncated():
    """Scripted: Empty-5x5 with max_steps=5 reaches the goal exactly on step 5."""
    mg = R.make_reference("MiniGrid-Empty-5x5-v0", max_steps=5)
    mg.reset(seed=0)
    env, state, _ = from_minigrid(mg)
    actions = np.array([2, 2, 1, 2, 2], np.int32)  # (1,1) right x2, turn down, down x2
    episode = R.record_episode(mg, actions, seed=0)
    assert episode.length == 5
    assert episode.steps["terminated"][4] and episode.steps["truncated"][4]
    obs0, outs = R.jax_rollout(R.config_env(env), R.stack([state]), actions[None])
    R.compare("Empty-5x5 max_steps=5", [episode], obs0, outs)
    assert bool(outs["terminated"][0, 4]) and bool(outs["truncated"][0, 4])
    assert abs(float(outs["reward"][0, 4]) - 0.1) < 1e-6


def _carry(mg, seed):
    colour = ("red", "blue", "purple", "grey")[seed % 4]
    mg.carrying = (Key, Ball, Box)[seed % 3](colour)


@pytest.mark.parametrize(
    "env_id",
    ["MiniGrid-DoorKey-8x8-v0", pytest.param("MiniGrid-LockedRoom-v0", marks=pytest.mark.slow)],
)
def test_starting_with_a_carried_object(env_id):
    """The agent starts holding a key, ball or box (set before converting) and drops it."""
    mg = R.make_reference(env_id)
    episodes = R.differential_run(mg, range(SEEDS), min(mg.max_steps, MAX_T), setup=_carry)
    v = mg.agent_view_size
    assert all(ep.obs0[v // 2, v - 1, 0] in (5, 6, 7) for ep in episodes)  # shown in the view
    drops = sum(R.coverage([ep])["drops"] > 0 for ep in episodes)
    assert drops >= SEEDS // 2, f"only {drops} episodes dropped the carried object"


MINIGRID_IDS = [i for i in jaxgrid.registered_ids() if i.startswith("MiniGrid-")]

# Natively generated levels: our reset states, copied into MiniGrid, step like MiniGrid (the
# larger two with ``-m slow``, like many more seeds of every registered level).
NATIVE = [
    "MiniGrid-DoorKey-5x5-v0",
    pytest.param("MiniGrid-DoorKey-8x8-v0", marks=pytest.mark.slow),
    "MiniGrid-LavaGapS7-v0",
    "MiniGrid-Empty-Random-5x5-v0",
    pytest.param("MiniGrid-Empty-8x8-v0", marks=pytest.mark.slow),
]


def _native(env_id, num, key_seed, constrained=False, **kw):
    env = jaxgrid.make(env_id, constraints=LEVEL_TABLE) if constrained else jaxgrid.make(env_id)
    mg = R.make_reference(env_id)
    cfg = R.config_env(env)
    mg.reset(seed=0)
    assert cfg == R.config_env(from_minigrid(mg)[0]), "defaults differ from MiniGrid's"
    reset = jax.jit(jax.vmap(env.reset), compiler_options=CHEAP)
    states, ts = reset(jax.random.split(jax.random.PRNGKey(key_seed), num))
    if constrained:  # MiniGrid holds the level's own state; jaxgrid steps the constrained one
        rollout_env, level_states = env, ConstrainedLevel.level_state(states)
    else:
        rollout_env, level_states = cfg, states
    num_steps = min(env.max_steps, MAX_T)
    actions = R.draw_actions(key_seed, num, num_steps)
    episodes = []
    for b in range(num):
        state = jax.tree.map(lambda x, b=b: x[b], level_states)
        mg.reset(seed=b)  # anything; then overwrite with our state
        R.set_minigrid_state(mg, state)
        episodes.append(R.record_episode(mg, actions[b], seed=b, **kw))
        np.testing.assert_array_equal(ts.observation["image"][b], episodes[-1].obs0)
    obs0, outs = R.jax_rollout(rollout_env, states, jax.numpy.asarray(actions))
    R.compare(f"native {env_id} key {key_seed}", episodes, obs0, outs)


@pytest.mark.parametrize("env_id", NATIVE)
def test_native_levels_step_like_minigrid(env_id):
    _native(env_id, SEEDS, key_seed=0)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", MINIGRID_IDS)
def test_native_levels_step_like_minigrid_many_seeds(env_id):
    # Levels with their own step rule step here under MiniGridEnv.step's rules (the core
    # dynamics on their layouts); their own test files step them under their own rules.
    own_rule = type(jaxgrid.make(env_id)).step is not Environment.step
    if "GoToDoor" in env_id:
        pytest.skip(
            "GoToDoor's doors sit in the outer wall: under MiniGridEnv.step an agent walks into "
            "one and faces out of the grid, where MiniGrid's Grid.get raises"
        )
    _native(env_id, SLOW_SEEDS, key_seed=7, encode_every_step=True, base_step=own_rule)


# Native resets with a constraint on: plain-step levels that can hold one (own-rule levels
# step under their own rules in the converted test above).
CONSTRAINED_NATIVE = [
    i for i in MINIGRID_IDS
    if _holds_a_target(i) and type(jaxgrid.make(i)).step is Environment.step
]  # fmt: skip


@pytest.mark.parametrize(
    "env_id",
    [pytest.param(i, marks=() if i == "MiniGrid-LavaGapS7-v0" else pytest.mark.slow)
     for i in CONSTRAINED_NATIVE],
)  # fmt: skip
def test_native_levels_step_like_minigrid_with_a_constraint(env_id):
    _native(env_id, SEEDS, key_seed=5, constrained=True, encode_every_step=True)


@pytest.mark.parametrize("env_id", MINIGRID_IDS)
def test_registered_defaults_match_minigrid(env_id):
    """Grid size, max_steps, view size and see_through_walls as MiniGrid sets them."""
    mg = R.make_reference(env_id)
    mg.reset(seed=0)
    assert R.config_env(jaxgrid.make(env_id)) == R.config_env(from_minigrid(mg)[0])
