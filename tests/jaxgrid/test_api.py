"""The environment API contract (DESIGN.md §2): make, overrides, jit/vmap, AutoReset, TimeStep."""

from __future__ import annotations

import functools

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers.xla import CHEAP

import jaxgrid
from jaxgrid import registry
from jaxgrid.constants import DONE, FORWARD, LEFT, NUM_ACTIONS, RIGHT
from jaxgrid.levels import DoorKey
from jaxgrid.wrappers import AutoReset

KEY = jax.random.PRNGKey(0)
MINIGRID_IDS = [i for i in jaxgrid.registered_ids() if i.startswith("MiniGrid-")]

GOAL_MAP = """
    ##########
    ##>>..G.##
    ##########
"""
LAVA_MAP = """
    ########
    ##>>V.##
    ########
"""


# --------------------------------------------------------------------------------- make


def test_registered_ids_include_minigrids_classic_levels():
    ids = jaxgrid.registered_ids()
    assert ids == sorted(ids)
    for n in (5, 6, 8, 16):
        assert f"MiniGrid-DoorKey-{n}x{n}-v0" in ids
        assert f"MiniGrid-Empty-{n}x{n}-v0" in ids
    for env_id in (
        "MiniGrid-Empty-Random-5x5-v0",
        "MiniGrid-LavaGapS5-v0",
        "MiniGrid-LavaGapS7-v0",
    ):
        assert env_id in ids


def test_make_unknown_id_lists_the_registered_ids():
    with pytest.raises(ValueError) as err:
        jaxgrid.make("MiniGrid-DoorKey-9x9-v0")
    message = str(err.value)
    assert "MiniGrid-DoorKey-9x9-v0" in message
    for env_id in jaxgrid.registered_ids():
        assert env_id in message


def test_make_unknown_override_names_it():
    with pytest.raises(ValueError, match="'colour'") as err:
        jaxgrid.make("MiniGrid-DoorKey-8x8-v0", view_size=5, colour=3)
    assert "view_size" in str(err.value)  # lists the valid settings


def test_overrides_work():
    env = jaxgrid.make("MiniGrid-DoorKey-8x8-v0", view_size=5, max_steps=100)
    assert (env.view_size, env.max_steps, env.width) == (5, 100, 8)
    state, ts = env.reset(KEY)
    assert ts.observation["image"].shape == (5, 5, 3)
    _, ts = env.step(state, LEFT)
    assert ts.observation["image"].shape == (5, 5, 3)
    default = jaxgrid.make("MiniGrid-DoorKey-8x8-v0")
    assert (default.view_size, default.max_steps) == (7, 640)  # the registry is not mutated
    assert jaxgrid.make("MiniGrid-Empty-8x8-v0", see_through_walls=False).see_through_walls is False


@pytest.mark.parametrize("view_size", [4, 2, 1, 0, -3, 8, 5.0, "7"])
def test_bad_view_size_is_rejected(view_size):
    with pytest.raises(ValueError, match="view_size"):
        jaxgrid.make("MiniGrid-DoorKey-8x8-v0", view_size=view_size)
    with pytest.raises(ValueError, match="view_size"):
        DoorKey(width=8, height=8, max_steps=10, view_size=view_size)


@pytest.mark.parametrize(
    "field, value",
    [("width", 0), ("height", -1), ("max_steps", 0), ("max_steps", 2.5), ("width", True)],
)
def test_bad_sizes_are_rejected(field, value):
    with pytest.raises(ValueError, match=field):
        jaxgrid.make("MiniGrid-DoorKey-8x8-v0", **{field: value})


def test_register_and_unregister():
    factory = lambda: DoorKey(width=6, height=6, max_steps=50)
    jaxgrid.register("Test-DoorKey-v0", factory)
    try:
        assert "Test-DoorKey-v0" in jaxgrid.registered_ids()
        assert jaxgrid.make("Test-DoorKey-v0").max_steps == 50
        with pytest.raises(ValueError, match="already registered"):
            jaxgrid.register("Test-DoorKey-v0", factory)
        with pytest.raises(ValueError, match="already registered"):
            jaxgrid.register("MiniGrid-DoorKey-8x8-v0", factory)
        jaxgrid.register("Test-DoorKey-v0", lambda: factory().replace(max_steps=7), overwrite=True)
        assert jaxgrid.make("Test-DoorKey-v0").max_steps == 7
    finally:
        registry.unregister("Test-DoorKey-v0")
    assert "Test-DoorKey-v0" not in jaxgrid.registered_ids()
    with pytest.raises(ValueError, match="'Test-DoorKey-v0' is not registered"):
        registry.unregister("Test-DoorKey-v0")
    with pytest.raises(ValueError, match="'MiniGrid-DoorKey-8x8-v0' is built in"):
        registry.unregister("MiniGrid-DoorKey-8x8-v0")
    # An overridden built-in id goes back to the built-in level.
    jaxgrid.register("MiniGrid-DoorKey-8x8-v0", factory, overwrite=True)
    try:
        assert jaxgrid.make("MiniGrid-DoorKey-8x8-v0").width == 6
    finally:
        registry.unregister("MiniGrid-DoorKey-8x8-v0")
    assert jaxgrid.make("MiniGrid-DoorKey-8x8-v0").width == 8


def test_env_is_static_configuration():
    a, b = jaxgrid.make("MiniGrid-DoorKey-8x8-v0"), jaxgrid.make("MiniGrid-DoorKey-8x8-v0")
    assert a == b and hash(a) == hash(b)
    assert jax.tree.leaves(a) == []  # nothing to trace: the whole env is static
    assert a.num_actions == NUM_ACTIONS == 7


# ------------------------------------------------------------------------- compile once

CASES = [
    "MiniGrid-DoorKey-8x8-v0",
    "MiniGrid-LavaGapS7-v0",
    "MiniGrid-Empty-Random-5x5-v0",
    "ascii",
    "autoreset",
]


def _env(case):
    if case == "ascii":
        return jaxgrid.from_ascii(GOAL_MAP, max_steps=4)
    if case == "autoreset":
        return AutoReset(jaxgrid.make("MiniGrid-DoorKey-5x5-v0", max_steps=5))
    return jaxgrid.make(case)


@pytest.mark.parametrize("case", CASES)
def test_step_and_reset_compile_once(case):
    chex.clear_trace_counter()
    env = _env(case)
    reset = jax.jit(chex.assert_max_traces(env.reset, n=1), compiler_options=CHEAP)
    step = jax.jit(chex.assert_max_traces(env.step, n=1), compiler_options=CHEAP)
    keys = jax.random.split(KEY, 4)
    for k in keys:
        state, ts = reset(k)
        for t in range(10):  # different states and actions, episodes ending on the way
            state, ts = step(state, jnp.int32((t * 3 + int(k[1])) % NUM_ACTIONS))


def test_equal_envs_share_one_compilation():
    chex.clear_trace_counter()

    @functools.partial(jax.jit, compiler_options=CHEAP)
    @chex.assert_max_traces(n=1)
    def step(env, state, action):
        return env.step(state, action)

    for _ in range(3):  # a fresh but equal env object each time: the jit cache still hits
        env = jaxgrid.make("MiniGrid-DoorKey-8x8-v0")
        state, _ = env.reset(KEY)
        step(env, state, jnp.int32(FORWARD))


@pytest.mark.parametrize("case", CASES)
def test_reset_and_step_timesteps_have_the_same_structure(case):
    # Needed to carry TimeSteps through lax.scan / select them with jnp.where.
    env = _env(case)
    state, ts0 = env.reset(KEY)
    state1, ts1 = env.step(state, jnp.int32(FORWARD))
    structure = lambda tree: jax.tree.map(lambda x: (jnp.shape(x), jnp.result_type(x)), tree)
    assert jax.tree.structure(ts0) == jax.tree.structure(ts1)
    assert structure(ts0) == structure(ts1)
    assert structure(state) == structure(state1)
    obs = ts0.observation
    assert obs["image"].dtype == jnp.uint8 and obs["image"].shape == (env.view_size,) * 2 + (3,)
    assert obs["direction"].dtype == jnp.int32 and obs["direction"].shape == ()
    assert ts0.reward.dtype == jnp.float32 and ts0.discount.dtype == jnp.float32
    assert ts0.terminated.dtype == jnp.bool_ and ts0.truncated.dtype == jnp.bool_
    assert float(ts0.reward) == 0.0 and not bool(ts0.done) and float(ts0.discount) == 1.0


# --------------------------------------------------------------------------- jit + vmap


@pytest.mark.parametrize("env_id", ["MiniGrid-DoorKey-8x8-v0", "MiniGrid-LavaGapS5-v0"])
def test_jit_vmap_over_a_batch_of_keys(env_id):
    env = jaxgrid.make(env_id)
    n = 16
    keys = jax.random.split(KEY, n)
    states, ts = jax.jit(jax.vmap(env.reset), compiler_options=CHEAP)(keys)
    v = env.view_size
    assert ts.observation["image"].shape == (n, v, v, 3)
    assert states.grid.shape == (n, env.width, env.height, 3)
    actions = jax.random.randint(jax.random.PRNGKey(1), (n,), 0, NUM_ACTIONS)
    states2, ts2 = jax.jit(jax.vmap(env.step), compiler_options=CHEAP)(states, actions)
    assert ts2.reward.shape == (n,) and ts2.terminated.shape == (n,)
    for i in (0, 5, n - 1):  # batched results equal the unbatched ones
        s, t = env.reset(keys[i])
        chex.assert_trees_all_equal(s, jax.tree.map(lambda x, i=i: x[i], states))
        chex.assert_trees_all_equal(t, jax.tree.map(lambda x, i=i: x[i], ts))
        s, t = env.step(s, actions[i])
        chex.assert_trees_all_equal(s, jax.tree.map(lambda x, i=i: x[i], states2))
        chex.assert_trees_all_equal(t, jax.tree.map(lambda x, i=i: x[i], ts2))
    if env_id.startswith("MiniGrid-DoorKey"):  # different keys, different layouts
        assert len({np.asarray(g).tobytes() for g in states.grid}) > n // 2


@functools.partial(jax.jit, static_argnums=(0, 2, 3), compiler_options=CHEAP)
def _rollout(env, key, num_envs=8, num_steps=64):
    """Random-action rollout with AutoReset under jit(vmap) in lax.scan."""
    auto = AutoReset(env)
    reset_key, act_key = jax.random.split(key)
    state, ts = jax.vmap(auto.reset)(jax.random.split(reset_key, num_envs))
    actions = jax.random.randint(act_key, (num_steps, num_envs), 0, NUM_ACTIONS)

    def body(state, a):
        new_state, ts = jax.vmap(auto.step)(state, a)
        return new_state, (state, new_state, ts)

    return jax.lax.scan(body, state, actions)[1]


def test_same_key_same_trajectory():
    env = jaxgrid.make("MiniGrid-DoorKey-5x5-v0", max_steps=20)
    a = _rollout(env, jax.random.PRNGKey(3))
    b = _rollout(env, jax.random.PRNGKey(3))
    chex.assert_trees_all_equal(a, b)
    c = _rollout(env, jax.random.PRNGKey(4))
    assert not np.array_equal(a[2].observation["image"], c[2].observation["image"])


# ------------------------------------------------------------------------------ AutoReset


def test_autoreset_on_truncation():
    env = jaxgrid.make("MiniGrid-Empty-5x5-v0", max_steps=3)
    auto = AutoReset(env)
    assert (auto.max_steps, auto.view_size, auto.num_actions) == (3, 7, 7)  # reads through
    state, ts = auto.reset(KEY)
    chex.assert_trees_all_equal(ts.info["final_observation"], ts.observation)
    for t in range(3):
        raw_state, raw_ts = env.step(state, LEFT)
        state, ts = auto.step(state, LEFT)
        chex.assert_trees_all_equal(ts.info["final_observation"], raw_ts.observation)
        if t < 2:
            assert int(state.step_count) == t + 1 and not bool(ts.done)
            chex.assert_trees_all_equal(ts.observation, raw_ts.observation)
    assert bool(ts.truncated) and not bool(ts.terminated)
    assert float(ts.reward) == 0.0 and float(ts.discount) == 1.0
    assert int(state.step_count) == 0  # a fresh episode
    assert int(state.agent_dir) == 0 and tuple(np.asarray(state.agent_pos)) == (1, 1)
    chex.assert_trees_all_equal(ts.observation, env.observe(state))
    # the final observation is the finished episode's: the agent had turned left three times
    assert int(ts.info["final_observation"]["direction"]) == 1
    assert int(ts.observation["direction"]) == 0


def test_autoreset_on_reaching_the_goal():
    level = jaxgrid.from_ascii(GOAL_MAP, max_steps=50)
    auto = AutoReset(level)
    start, ts0 = auto.reset(KEY)
    state, ts = auto.step(start, FORWARD)
    assert not bool(ts.done)
    raw_state, raw_ts = level.step(state, FORWARD)  # what the finished episode looked like
    state, ts = auto.step(state, FORWARD)
    assert bool(ts.terminated) and not bool(ts.truncated)
    assert abs(float(ts.reward) - (1 - 0.9 * 2 / 50)) < 1e-6
    assert float(ts.discount) == 0.0
    assert tuple(np.asarray(raw_state.agent_pos)) == (3, 1)  # the agent stood on the goal
    chex.assert_trees_all_equal(ts.info["final_observation"], raw_ts.observation)
    assert not np.array_equal(ts.info["final_observation"]["image"], ts.observation["image"])
    # the returned state is the start of a new episode
    assert int(state.step_count) == 0
    chex.assert_trees_all_equal(state.replace(key=start.key), start)
    chex.assert_trees_all_equal(ts.observation, ts0.observation)


def test_autoreset_invariants_under_vmap_and_scan():
    env = jaxgrid.make("MiniGrid-DoorKey-5x5-v0", max_steps=9)
    before, after, ts = _rollout(env, jax.random.PRNGKey(0), 16, 60)
    done = np.asarray(ts.terminated | ts.truncated)
    assert done.sum() > 50  # episodes end by truncation every 9 steps (or earlier)
    count = np.asarray(after.step_count)
    np.testing.assert_array_equal(count, np.where(done, 0, np.asarray(before.step_count) + 1))
    observed = jax.jit(jax.vmap(jax.vmap(env.observe)), compiler_options=CHEAP)(after)
    chex.assert_trees_all_equal(ts.observation, observed)
    final, obs = ts.info["final_observation"], ts.observation
    same = (np.asarray(final["image"]) == np.asarray(obs["image"])).all(axis=(2, 3, 4))
    assert same[~done].all()
    np.testing.assert_array_equal(np.asarray(ts.discount), 1.0 - np.asarray(ts.terminated))
    # fresh episodes are freshly drawn layouts, not copies of the first one
    fresh = np.asarray(after.grid)[done]
    assert len({g.tobytes() for g in fresh}) > 1


# --------------------------------------------------------------------------- discount


@pytest.mark.parametrize(
    "text, max_steps, terminated, truncated, discount",
    [
        (LAVA_MAP, 10, True, False, 0.0),
        (GOAL_MAP, 10, False, False, 1.0),  # one step short of the goal
        (LAVA_MAP, 1, True, True, 0.0),
        (GOAL_MAP, 1, False, True, 1.0),
    ],
)
def test_discount_is_zero_only_on_termination(text, max_steps, terminated, truncated, discount):
    level = jaxgrid.from_ascii(text, max_steps=max_steps)
    state, _ = level.reset(KEY)
    state, ts = level.step(state, FORWARD)
    assert (bool(ts.terminated), bool(ts.truncated)) == (terminated, truncated)
    assert float(ts.discount) == discount
    assert bool(ts.done) == (terminated or truncated)


def test_done_and_turn_actions_keep_the_position():
    env = jaxgrid.make("MiniGrid-Empty-8x8-v0")
    state, _ = env.reset(KEY)
    for action in (DONE, LEFT, RIGHT):
        new, _ = env.step(state, action)
        assert tuple(np.asarray(new.agent_pos)) == tuple(np.asarray(state.agent_pos))
