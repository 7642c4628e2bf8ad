"""Nothing silently wrong: impossible worlds, bad actions, bad keys and unsupported conversions
raise clear errors before any compile, and every legal world is well formed and solvable.

* Worlds: each level states its minimum size; smaller ones raise ``ValueError`` naming the
  setting and the minimum. Every registered id, reset at its minimum size and at random legal
  sizes, puts agent, goal, doors, keys and lava on legal cells, and the oracle solves every
  episode without a violation.
* Actions and keys: concrete bad values raise ``TypeError``/``ValueError``; traced values are
  untouched (out-of-range actions still act as ``done``, ``jit`` compiles once, ``vmap`` works).
* gymnasium: actions are checked against the action space; ``render()`` without a mode warns.
* ``from_minigrid``: levels with their own ``step`` and non-MiniGrid envs are refused.
"""

from __future__ import annotations

import functools
import warnings
import zlib

import chex
import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxgrid
import jaxgrid.gym as jgym
from jaxgrid.compat import from_minigrid
from jaxgrid.constants import DONE, DOOR, EMPTY, GOAL, KEY, LAVA, LOCKED, WALL
from jaxgrid.levels import FixedLevel
from jaxgrid.oracle import rollout_oracle

KEY0 = jax.random.PRNGKey(0)
IDS = jaxgrid.registered_ids()  # the built-in ids (collected before any test registers one)
EPISODES = 32  # per (id, size), in one jitted call


def _min_sizes(env) -> list[tuple[int, int]]:
    """The smallest legal sizes: the stated minimum, or its two neighbours where the corner
    itself is refused (Empty's 3x3 has no room for both agent and goal)."""
    mw, mh, _ = env.min_size()
    sizes = [(mw, mh)] if _legal(env, mw, mh) else [(mw + 1, mh), (mw, mh + 1)]
    assert all(_legal(env, *s) for s in sizes), sizes
    return sizes


def _legal(env, width, height) -> bool:
    try:
        env.replace(width=width, height=height)
    except ValueError:
        return False
    return True


def _random_sizes(env_id, env, count) -> list[tuple[int, int]]:
    mw, mh, _ = env.min_size()
    rng = np.random.default_rng(zlib.crc32(env_id.encode()))
    sizes = []
    while len(sizes) < count:
        size = (int(rng.integers(mw, mw + 10)), int(rng.integers(mh, mh + 8)))
        if _legal(env, *size) and size not in sizes:
            sizes.append(size)
    return sizes


# (doors, keys) each level places; lava is counted separately (it depends on the size).
OBJECTS = {"Empty": (0, 0), "DoorKey": (1, 1), "LavaGap": (0, 0), "TwoRooms": (2, 0)}
OBJECTS["ThreeRoomsKey"] = (2, 1)


def _expected_lava(env) -> int:
    name = type(env).__name__
    if name == "LavaGap":
        return env.height - 3  # the interior column minus its one-cell gap
    return int(name == "TwoRooms" and env.has_lava)


@jax.jit
def _resets_and_oracle(env, key):
    states, _ = jax.vmap(env.reset)(jax.random.split(key, EPISODES))
    return states, rollout_oracle(env, key, EPISODES)  # the same resets, then the oracle


def _check_world(env_id, width, height):
    env = jaxgrid.make(env_id, width=width, height=height)
    states, result = jax.device_get(_resets_and_oracle(env, KEY0))
    doors, keys = OBJECTS[type(env).__name__]
    # Rows of a door's wall that may be open: ThreeRoomsKey's second wall has a bottom-row gap.
    gaps = {height - 2} if type(env).__name__ == "ThreeRoomsKey" else set()
    where = f"{env_id} at {width}x{height}"
    for i in range(EPISODES):
        grid, kind = states.grid[i], states.grid[i, ..., 0]
        assert kind.shape == (width, height), where
        ring = np.concatenate([kind[0], kind[-1], kind[:, 0], kind[:, -1]])
        assert (ring == WALL).all(), f"{where}: an object replaced the outer wall"
        x, y = states.agent_pos[i]
        assert 0 < x < width - 1 and 0 < y < height - 1, where
        assert kind[x, y] == EMPTY, f"{where}: the agent starts on object {kind[x, y]}"
        assert (kind == GOAL).sum() == 1, f"{where}: {(kind == GOAL).sum()} goals"
        if hasattr(states.extras, "goal_pos"):
            assert kind[tuple(states.extras.goal_pos[i])] == GOAL, where
        door_cells = np.argwhere(kind == DOOR)
        assert len(door_cells) == doors, f"{where}: {len(door_cells)} doors"
        for dx, dy in door_cells:  # in a vertical wall, leading across it
            openings = np.flatnonzero(~np.isin(kind[dx, 1:-1], [WALL, DOOR])) + 1
            assert set(openings.tolist()) <= gaps, f"{where}: door ({dx}, {dy}) not in a wall"
            assert kind[dx - 1, dy] != WALL and kind[dx + 1, dy] != WALL, where
        key_cells = np.argwhere(kind == KEY)
        assert len(key_cells) == keys, f"{where}: {len(key_cells)} keys"
        locked = grid[kind == DOOR][grid[kind == DOOR][:, 2] == LOCKED]
        for kx, ky in key_cells:  # the key opens the locked door
            assert len(locked) == 1 and grid[kx, ky, 1] == locked[0, 1], where
        assert (kind == LAVA).sum() == _expected_lava(env), where
    assert result["success"].all(), f"{where}: the oracle failed {(~result['success']).sum()}"
    assert (result["violations"] == 0).all(), f"{where}: the oracle had to violate"


@pytest.mark.parametrize("env_id", IDS)
def test_every_id_is_legal_and_solvable_at_its_minimum_size(env_id):
    env = jaxgrid.make(env_id)
    for size in _min_sizes(env):
        _check_world(env_id, *size)


@pytest.mark.slow
@pytest.mark.parametrize("env_id", IDS)
def test_every_id_is_legal_and_solvable_at_many_sizes(env_id):
    env = jaxgrid.make(env_id)
    for size in _random_sizes(env_id, env, 6):
        _check_world(env_id, *size)


@pytest.mark.parametrize("env_id", IDS)
def test_below_the_minimum_size_raises_naming_the_setting_and_minimum(env_id):
    env = jaxgrid.make(env_id)
    mw, mh, _ = env.min_size()
    with pytest.raises(ValueError, match=rf"\.width must be at least {mw} "):
        jaxgrid.make(env_id, width=mw - 1)
    with pytest.raises(ValueError, match=rf"\.height must be at least {mh} "):
        jaxgrid.make(env_id, height=mh - 1)


@pytest.mark.parametrize(
    "env_id, overrides, message",
    [
        ("MiniGrid-Empty-8x8-v0", dict(width=1, height=1), r"Empty\.width must be at least 3"),
        ("MiniGrid-Empty-8x8-v0", dict(width=3, height=3), r"cannot both be 3"),
        ("TwoRooms-v0", dict(width=2), r"TwoRooms\.width must be at least 5"),
        ("TwoRooms-v0", dict(height=3), r"TwoRooms\.height must be at least 4"),
        ("TwoRoomsLava-v0", dict(width=6), r"TwoRooms\.width must be at least 7"),
        ("MiniGrid-DoorKey-8x8-v0", dict(width=3), r"DoorKey\.width must be at least 5"),
        ("MiniGrid-LavaGapS5-v0", dict(width=4), r"LavaGap\.width must be at least 5"),
        ("ThreeRoomsKey-v0", dict(width=5), r"ThreeRoomsKey\.width must be at least 7"),
        ("TwoRooms-v0", dict(view_size=4), r"view_size must be an odd int"),
    ],
)
def test_impossible_worlds_raise_at_make(env_id, overrides, message):
    with pytest.raises(ValueError, match=message):
        jaxgrid.make(env_id, **overrides)


def test_fixed_level_agent_must_start_inside_on_a_standable_cell():
    level = jaxgrid.from_ascii(
        """
        ##########
        ##>>..##G.
        ##..KYLY..
        ##########
        """
    )
    assert level.agent_start == (1, 1)
    with pytest.raises(ValueError, match=r"agent_start \(0, 0\) is on a wall"):
        level.replace(agent_start=(0, 0))
    with pytest.raises(ValueError, match=r"agent_start \(2, 2\) is on a key"):
        level.replace(agent_start=(2, 2))
    with pytest.raises(ValueError, match=r"agent_start \(5, 1\) is outside the 5x4 grid"):
        level.replace(agent_start=(5, 1))
    with pytest.raises(ValueError, match=r"agent_dir must be 0\.\.3 or -1"):
        level.replace(agent_dir=4)
    assert isinstance(level.replace(agent_start=(4, 1)), FixedLevel)  # the goal: allowed


# --------------------------------------------------------------------------- actions and keys

ENVS = ["MiniGrid-Empty-5x5-v0", "TwoRooms-v0"]  # Environment.step and Scenario.step


@functools.cache
def _start(env_id):
    """``(env, first state)``; the reset is jitted (op-by-op it compiles every small op)."""
    env = jaxgrid.make(env_id)
    return env, jax.jit(env.reset)(KEY0)[0]


@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize(
    "action, error, message",
    [
        (2.7, TypeError, r"action must be an integer scalar .* got float 2\.7"),
        (2.0, TypeError, r"got float 2\.0"),
        ("2", TypeError, r"got str '2'"),
        (True, TypeError, r"got bool True"),
        ([2], TypeError, r"got list \[2\]"),
        (np.float32(1), TypeError, r"got dtype float32"),
        (jnp.array(1.5), TypeError, r"got dtype float32"),
        (np.array([2, 2]), ValueError, r"action .* got an array of shape \(2,\).*jax\.vmap"),
        (jnp.array([[2]]), ValueError, r"got an array of shape \(1, 1\)"),
    ],
)
def test_concrete_bad_actions_raise(env_id, action, error, message):
    env, state = _start(env_id)
    with pytest.raises(error, match=message):
        env.step(state, action)


@pytest.mark.parametrize("env_id", ENVS)
@pytest.mark.parametrize(
    "key, error, message",
    [
        (0, TypeError, r"reset's key must be one PRNG key.* got int 0"),
        (jnp.zeros(2), TypeError, r"got an array of dtype float32"),
        (np.zeros(2, np.int32), TypeError, r"got an array of dtype int32"),
        (jax.random.split(KEY0, 3), ValueError, r"got shape \(3, 2\).*jax\.vmap\(env\.reset\)"),
        (jax.random.split(jax.random.key(0), 3), ValueError, r"\(shape \(\)\), got shape \(3,\)"),
        (np.zeros(3, np.uint32), ValueError, r"\(shape \(2,\)\), got shape \(3,\)"),
    ],
)
def test_concrete_bad_keys_raise(env_id, key, error, message):
    env = jaxgrid.make(env_id)
    with pytest.raises(error, match=message):
        env.reset(key)


def test_every_integer_kind_is_an_action_and_out_of_range_acts_as_done():
    # Regression guard: the checks accept every integer scalar and keep the documented rule.
    env, state = _start("TwoRooms-v0")
    done, _ = env.step(state, DONE)
    for action in (2, np.int64(2), np.array(2, np.uint8), jnp.int32(2), jnp.array(2)):
        chex.assert_trees_all_equal(env.step(state, action), env.step(state, 2))
    for action in (7, -1, 2**20, jnp.int32(9)):
        chex.assert_trees_all_equal(env.step(state, action)[0], done)
    env = jaxgrid.make("MiniGrid-Empty-5x5-v0")  # a cheap reset to run op by op
    assert jax.random.key_data(env.reset(jax.random.key(3))[0].key).shape == (2,)
    chex.assert_trees_all_equal(env.reset(np.asarray(KEY0)), env.reset(KEY0))


def test_traced_actions_and_keys_are_untouched():
    # Regression guard: jit compiles once for every action, out-of-range acts as done under
    # jit, and vmap of reset and step works on batches.
    env, state = _start("TwoRooms-v0")
    done, _ = jax.jit(env.step)(state, DONE)
    step = jax.jit(chex.assert_max_traces(env.step, n=1))
    for action in (0, 2, 9, -3):
        out, _ = step(state, jnp.int32(action))
        if action in (9, -3):
            chex.assert_trees_all_equal(out, done)
    keys = jnp.stack([KEY0, KEY0, KEY0, KEY0])
    states, _ = jax.jit(jax.vmap(env.reset))(keys)
    chex.assert_trees_all_equal(jax.tree.map(lambda x: x[1], states), _start("TwoRooms-v0")[1])
    states, ts = jax.jit(jax.vmap(env.step))(states, jnp.array([0, 2, 9, 5]))
    assert ts.reward.shape == (4,)


# --------------------------------------------------------------------------------- gymnasium


@pytest.mark.parametrize("action", [7, -1, 2.5, 2.0, "2", np.float32(1), [2], np.array([2])])
def test_gym_step_rejects_actions_outside_the_space(action):
    env = gym.make("jaxgrid/MiniGrid-Empty-5x5-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action .* is not in Discrete\(7\)"):
        env.step(action)


def test_gym_step_accepts_the_space_members_and_jax_integers():
    env = gym.make("jaxgrid/MiniGrid-Empty-5x5-v0")
    env.reset(seed=0)
    for action in (1, np.int64(2), np.array(0), jnp.int32(2)):
        env.step(action)


@pytest.mark.parametrize(
    "actions", [[7, 0, 0], [-1, 0, 0], [2.5, 1, 1], [1, 1], np.zeros((1, 3), int), 2, "abc"]
)
def test_gym_vector_step_rejects_actions_outside_the_space(actions):
    envs = jgym.JaxGridVectorEnv("MiniGrid-Empty-5x5-v0", 3)
    envs.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions .* is not in MultiDiscrete\(\[7 7 7\]\)"):
        envs.step(actions)
    envs.step([0, 1, 2])
    envs.step(jnp.array([0, 1, 2]))


def test_gym_render_without_a_mode_warns_like_gymnasium():
    message = r"You are calling render method without specifying any render mode"
    env = gym.make("jaxgrid/MiniGrid-Empty-5x5-v0")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match=message + r".*jaxgrid/MiniGrid-Empty-5x5-v0"):
        assert env.render() is None
    envs = jgym.JaxGridVectorEnv("MiniGrid-Empty-5x5-v0", 2)
    envs.reset(seed=0)
    with pytest.warns(UserWarning, match=message + r".*JaxGridVectorEnv\(\"MiniGrid-Empty"):
        assert envs.render() is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # with a mode: no warning
        env = gym.make("jaxgrid/MiniGrid-Empty-5x5-v0", render_mode="ansi")
        env.reset(seed=0)
        assert isinstance(env.render(), str)


# ----------------------------------------------------------------------------- from_minigrid

# MiniGrid levels whose class overrides MiniGridEnv.step (rules of their own).
OWN_STEP = [
    "MiniGrid-Unlock-v0",
    "MiniGrid-UnlockPickup-v0",
    "MiniGrid-BlockedUnlockPickup-v0",
    "MiniGrid-Dynamic-Obstacles-5x5-v0",
    "MiniGrid-MemoryS7-v0",
    "MiniGrid-Fetch-5x5-N2-v0",
    "MiniGrid-GoToDoor-5x5-v0",
    "MiniGrid-GoToObject-6x6-N2-v0",
    "MiniGrid-PutNear-6x6-N2-v0",
    "MiniGrid-RedBlueDoors-6x6-v0",
    "MiniGrid-KeyCorridorS3R1-v0",
]


def _minigrid(env_id):
    import minigrid  # noqa: F401  (registers the MiniGrid ids)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mg = gym.make(env_id)
    mg.reset(seed=0)
    return mg


@pytest.mark.parametrize("env_id", OWN_STEP)
def test_from_minigrid_refuses_levels_with_their_own_step(env_id):
    mg = _minigrid(env_id)
    name = type(mg.unwrapped).__name__
    with pytest.raises(ValueError, match=rf"{name} overrides MiniGridEnv\.step: its own step"):
        from_minigrid(mg)
    env, state, _ = from_minigrid(mg, base_step=True)  # explicitly: the layout, base rules
    assert env.grid.shape == (mg.unwrapped.width, mg.unwrapped.height, 3)


def test_from_minigrid_converts_levels_with_the_base_step():
    # Regression guard: levels stepping with MiniGridEnv.step itself convert as before.
    for env_id in ("MiniGrid-DoorKey-5x5-v0", "MiniGrid-FourRooms-v0", "MiniGrid-LavaGapS5-v0"):
        env, _, _ = from_minigrid(_minigrid(env_id))
        assert isinstance(env, FixedLevel)


@pytest.mark.parametrize("env_id, name", [("CartPole-v1", "CartPoleEnv"), (None, "object")])
def test_from_minigrid_refuses_what_is_not_a_minigrid_env(env_id, name):
    env = object() if env_id is None else gym.make(env_id)
    with pytest.raises(ValueError, match=rf"got {name}, which is not a MiniGrid env"):
        from_minigrid(env)
