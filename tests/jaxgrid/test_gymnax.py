"""jaxgrid.gymnax: gymnax's spaces hold the observations, gymnax's ``step`` auto-resets into
the same episodes jaxgrid steps raw, every id traces, and PPO written for gymnax learns."""

from __future__ import annotations

import ast
import pathlib
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnax.environments import environment, spaces
from helpers import gymnax_ppo
from helpers.xla import CHEAP

import jaxgrid
import jaxgrid.gymnax as jgx
from jaxgrid import language
from jaxgrid.constrained import language_table
from jaxgrid.sentences import HAZARD_ROOMS, PAPER

# Forward-heavy random actions, with toggles so that doors open and scenarios see violations.
ACTION_PROBS = np.array([0.15, 0.15, 0.45, 0.03, 0.03, 0.16, 0.03])


def _actions(seed: int, shape) -> np.ndarray:
    return np.random.default_rng(seed).choice(7, size=shape, p=ACTION_PROBS).astype(np.int32)


def _one_hot_reference(obs: dict, vocab: int) -> np.ndarray:
    """MiniGrid's OneHotPartialObsWrapper per cell (type 11, colour 6, state 3), flattened in
    [x, y] order, then the direction one-hot, then each constraint token one-hot (numpy)."""
    image = np.asarray(obs["image"])
    batch = image.shape[:-3]
    cells = np.concatenate(
        [np.eye(11)[image[..., 0]], np.eye(6)[image[..., 1]], np.eye(3)[image[..., 2]]], -1
    )
    parts = [cells.reshape(batch + (-1,)), np.eye(4)[np.asarray(obs["direction"])]]
    if "constraint" in obs:
        parts.append(np.eye(vocab)[np.asarray(obs["constraint"])].reshape(batch + (-1,)))
    return np.concatenate(parts, -1).astype(np.float32)


def _rollout(env, params, num_envs: int, actions):
    """Jitted ``vmap(reset)`` then ``vmap(step)`` over ``actions`` (T, num_envs): the reset's
    observation, every step's outputs, and where each step's observation is in the space."""
    space = env.observation_space(params)

    def run(key, actions):
        keys = jax.random.split(key, num_envs)
        obs0, state = jax.vmap(env.reset, in_axes=(0, None))(keys, params)

        def body(state, xs):
            k, a = xs
            out = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k, num_envs), state, a, params
            )
            return out[1], (out, jax.vmap(space.contains)(out[0]))

        steps = jax.random.split(jax.random.fold_in(key, 1), len(actions))
        return obs0, jax.vmap(space.contains)(obs0), jax.lax.scan(body, state, (steps, actions))

    return jax.jit(run, compiler_options=CHEAP)(jax.random.PRNGKey(0), jnp.asarray(actions))


def _check_shapes(space, obs) -> None:
    """What gymnax's ``contains`` leaves out: shapes (after leading axes) and dtypes."""
    if isinstance(space, spaces.Dict):
        assert isinstance(obs, jgx.Observation) and set(obs) == set(space.spaces)
        for k, sub in space.spaces.items():
            _check_shapes(sub, obs[k])
            assert obs[k] is getattr(obs, k)
        return
    assert obs.shape[obs.ndim - len(space.shape) :] == tuple(space.shape)
    assert obs.dtype == jnp.dtype(space.dtype)


# --- spaces, jit, vmap ------------------------------------------------------------------------
# The flat observations of a scenario and a MiniGrid level meet their space in
# test_episodes_equal_jaxgrid_raw_steps_with_gymnax_auto_reset (one compile for both checks).
@pytest.mark.parametrize("env_id", ["TwoRooms-v0", "MiniGrid-DoorKey-5x5-v0"])
def test_dict_observations_are_jaxgrid_s_own_and_in_their_space(env_id):
    env, params = jgx.make(env_id, observation="dict")
    space = env.observation_space(params)
    assert isinstance(space, spaces.Dict)
    obs0, inside0, (_, (out, inside)) = _rollout(env, params, 4, _actions(0, (12, 4)))
    assert bool(jnp.all(inside0)) and bool(jnp.all(inside)), "an observation outside its space"
    _check_shapes(space, obs0)
    _check_shapes(space, out[0])
    _check_shapes(space, out[-1]["final_observation"])
    keys = jax.random.split(jax.random.PRNGKey(0), 4)  # _rollout's reset keys
    _, ts = jax.jit(jax.vmap(jaxgrid.make(env_id).reset), compiler_options=CHEAP)(keys)
    assert set(ts.observation) == set(obs0)
    for k, v in ts.observation.items():
        np.testing.assert_array_equal(obs0[k], v)
    first = jax.tree.map(lambda x: x[0], obs0)
    assert bool(space.contains(first))
    assert not bool(space.contains(jgx.Observation({**first, "direction": jnp.int32(4)})))
    if "constraint" in first:
        bad = jgx.Observation({**first, "constraint": first["constraint"].at[0].set(23)})
        assert not bool(space.contains(bad))


def test_flat_sizes_are_the_documented_ones():
    ids = ["MiniGrid-Empty-6x6-v0", "TwoRooms-v0", "HazardRooms-v0"]
    sizes = {i: jgx.make(i)[0].observation_space(None).shape for i in ids}
    # 7x7 view: 49 cells x 20 + 4 directions; + 13 tokens x 23 ids; + 32 tokens x 73 ids.
    assert sizes == {ids[0]: (984,), ids[1]: (5 * 5 * 20 + 4 + 13 * 23,), ids[2]: (3320,)}
    assert (PAPER.max_len, PAPER.vocab_size) == (13, 23)
    assert (HAZARD_ROOMS.max_len, HAZARD_ROOMS.vocab_size) == (32, 73)
    assert (language.MAX_LEN, language.vocab_size()) == (32, 73)


# --- the same episodes as jaxgrid's own step -------------------------------------------------
@pytest.mark.parametrize(
    "env_id, max_steps, ends, violations",
    [
        ("MiniGrid-LavaGapS5-v0", 20, 3, 0),
        ("TwoRoomsLava-v0", 30, 3, 1),
        # HazardRooms compiles for a while: its cost/violation split is traced by default below.
        pytest.param("HazardRooms-v0", 40, 0, 1, marks=pytest.mark.slow),
    ],
)
def test_episodes_equal_jaxgrid_raw_steps_with_gymnax_auto_reset(
    env_id, max_steps, ends, violations
):
    """gymnax's ``step`` on the adapter vs ``jaxgrid.make(id)`` stepped raw, reset by hand
    where an episode ended, from the key gymnax's ``step`` gives ``reset_env``."""
    n, steps = 16, 120
    env, params = jgx.make(env_id, max_steps=max_steps)
    raw = jaxgrid.make(env_id, max_steps=max_steps)
    vocab = language_table(raw).vocab_size
    assert isinstance(env, environment.Environment) and env.name == env_id
    assert isinstance(env.action_space(params), spaces.Discrete)
    assert env.action_space(params).n == env.num_actions == 7
    space = env.observation_space(params)
    assert isinstance(space, spaces.Box)

    def run(key, actions):
        keys = jax.random.split(key, n)
        obs, gstate = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
        inside0 = jax.vmap(space.contains)(obs)
        rstate, rts = jax.vmap(raw.reset)(keys)

        def body(carry, xs):
            gstate, rstate = carry
            k, a = xs
            ks = jax.random.split(k, n)
            obs, gstate, reward, term, trunc, info = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                ks, gstate, a, params
            )
            rstate, rts = jax.vmap(raw.step)(rstate, a)
            # gymnax's step: key_step, key_reset = split(key); reset_env(key_reset) on done.
            fresh, fresh_ts = jax.vmap(raw.reset)(jax.vmap(jax.random.split)(ks)[:, 1])
            done = rts.terminated | rts.truncated
            pick = jax.vmap(lambda d, a, b: jax.tree.map(lambda x, y: jnp.where(d, x, y), a, b))
            rstate = pick(done, fresh, rstate)
            next_obs = pick(done, fresh_ts.observation, rts.observation)
            got = (obs, reward, term, trunc, info, gstate.time, jax.vmap(space.contains)(obs))
            want = (next_obs, rts, rstate.step_count)
            return (gstate, rstate), (got, want)

        ks = jax.random.split(jax.random.fold_in(key, 1), steps)
        scan = jax.lax.scan(body, (gstate, rstate), (ks, actions))[1]
        return obs, inside0, rts.observation, scan

    jitted = jax.jit(run, compiler_options=CHEAP)
    obs0, inside0, raw_obs0, (got, want) = jax.device_get(
        jitted(jax.random.PRNGKey(3), jnp.asarray(_actions(1, (steps, n))))
    )
    obs, reward, term, trunc, info, time_, inside = got
    next_obs, rts, step_count = want
    assert inside0.all() and inside.all(), "an observation outside its space"
    _check_shapes(space, obs0)
    _check_shapes(space, obs)
    assert set(np.unique(obs)) == {0.0, 1.0}
    assert not bool(space.contains(jnp.asarray(obs0[0]).at[3].set(2.0)))  # the check can fail
    np.testing.assert_array_equal(obs0, _one_hot_reference(raw_obs0, vocab))
    np.testing.assert_array_equal(obs, _one_hot_reference(next_obs, vocab))
    np.testing.assert_array_equal(
        info["final_observation"], _one_hot_reference(rts.observation, vocab)
    )
    np.testing.assert_array_equal(reward, rts.reward)
    np.testing.assert_array_equal(term, rts.terminated)
    np.testing.assert_array_equal(trunc, rts.truncated)
    np.testing.assert_array_equal(info["terminated"], term)
    np.testing.assert_array_equal(info["truncated"], trunc)
    np.testing.assert_array_equal(time_, step_count)  # 0 right after an auto-reset
    violation = rts.info.get("violation", np.zeros_like(term))
    np.testing.assert_array_equal(info["violation"], violation)
    np.testing.assert_array_equal(info["cost"], rts.info.get("cost", violation.astype(
        np.float32)))  # fmt: skip
    assert info["cost"].dtype == np.float32
    if "template_id" in rts.info:
        np.testing.assert_array_equal(info["template_id"], rts.info["template_id"])
    # The comparison covered what it claims: both kinds of episode end, and auto-resets.
    assert term.sum() >= ends and trunc.sum() >= 3 and (time_ == 0).sum() >= 6
    assert violation.sum() >= violations


def test_hazard_rooms_cost_is_its_own():
    """HazardRooms' ``cost`` counts costly events within a budget too, and passes through as
    it is (traced, not compiled: cheap)."""
    env, params = jgx.make("HazardRooms-v0")

    def one(key):
        obs, state = env.reset(key, params)
        return env.step_env(key, state, jnp.int32(2), params)[-1]

    info = jax.eval_shape(one, jax.random.PRNGKey(0))
    assert {"cost", "violation", "satisfiable"} <= set(info)
    assert info["cost"].dtype == jnp.float32 and info["violation"].dtype == jnp.bool_
    jgx_info = jgx._info(
        {"violation": jnp.array(False), "cost": jnp.float32(1.0), "template_id": jnp.int32(3)}
    )
    assert float(jgx_info["cost"]) == 1.0 and not bool(jgx_info["violation"])
    plain = jgx._info({})
    assert float(plain["cost"]) == 0.0 and not bool(plain["violation"])
    assert int(jgx_info["template_id"]) == 3


# --- params -----------------------------------------------------------------------------------
def test_truncation_is_the_first_of_the_env_s_max_steps_and_the_params_without_recompile(
    compiles,
):
    env, params = jgx.make("MiniGrid-Empty-5x5-v0", max_steps=8)
    assert isinstance(params, jgx.EnvParams) and isinstance(params, environment.EnvParams)
    assert params.max_steps_in_episode == env.jax_env.max_steps == 8
    assert (
        params.settings == {} and jgx.make("MiniGrid-Empty-5x5-v0")[1].max_steps_in_episode == 100
    )

    @jax.jit
    def left_turns(params):
        _, state = env.reset(jax.random.PRNGKey(0), params)

        def body(state, k):
            out = env.step(k, state, jnp.int32(0), params)
            return out[1], (out[3], out[4], out[1].time)

        return jax.lax.scan(body, state, jax.random.split(jax.random.PRNGKey(1), 12))[1]

    ends, compiled = {}, None
    for limit in (8, 5, 1000):
        term, trunc, time_ = jax.device_get(left_turns(params.replace(max_steps_in_episode=limit)))
        compiled = len(compiles) if compiled is None else compiled
        assert len(compiles) == compiled, "a new max_steps_in_episode recompiled"
        assert not term.any()
        ends[limit] = np.flatnonzero(trunc).tolist()
        assert time_.tolist() == [(i + 1) % min(limit, 8) for i in range(12)]  # 0: auto-reset
    assert ends == {8: [7], 5: [4, 9], 1000: [7]}  # 1000: jaxgrid's own max_steps ends it


def test_scenario_settings_in_params_can_be_vmapped():
    """``absent_colour_prob`` 0 vs 1 in one compiled reset: the constraint names a door of the
    episode always, or never."""
    env, params = jgx.make("TwoRooms-v0")
    assert params.settings == {"absent_colour_prob": 0.2}
    probs = jnp.array([0.0, 1.0])
    batch = params.replace(settings={"absent_colour_prob": probs})
    keys = jax.random.split(jax.random.PRNGKey(0), 32)
    axes = jgx.EnvParams(max_steps_in_episode=None, settings={"absent_colour_prob": 0})
    reset = jax.vmap(jax.vmap(env.reset, in_axes=(0, None)), in_axes=(None, axes))
    _, state = jax.jit(reset, compiler_options=CHEAP)(keys, batch)
    inner = state.inner
    colour = inner.extras.constraint.door_colour  # (2, 32)
    grids = inner.grid
    is_door = grids[..., 0] == jaxgrid.constants.DOOR
    present = jnp.any(is_door & (grids[..., 1] == colour[..., None, None]), axis=(-2, -1))
    assert bool(present[0].all()) and not bool(present[1].any())


# --- every id ---------------------------------------------------------------------------------
SCENARIOS = {"TwoRooms-v0", "TwoRoomsLava-v0", "ThreeRoomsKey-v0", "HazardRooms-v0"}
# One id per jaxgrid level class (25 of the 80) has its step traced too: step_env's code is
# the same for every id of a class, and tracing a step costs as much as tracing two resets.
ONE_ID_PER_LEVEL = set(
    {type(jaxgrid.make(i)): i for i in reversed(jaxgrid.registered_ids())}.values()
)


@pytest.mark.parametrize("env_id", jaxgrid.registered_ids())
def test_every_id_makes_and_traces_within_its_spaces(env_id):
    """Every id is made in both observation modes and its reset traced (``eval_shape``: no
    compile, so all 80 fit the default run), its step too for one id per level class; outputs
    match the spaces' shapes and dtypes. Compiled runs of every id: ``test_every_id_runs``
    (slow)."""
    env, params = jgx.make(env_id)
    stepped = env_id in ONE_ID_PER_LEVEL

    def reset_step(key):
        obs, state = env.reset(key, params)
        return obs, state, env.step(key, state, jnp.int32(2), params) if stepped else None

    obs, state, out = jax.eval_shape(reset_step, jax.random.PRNGKey(0))
    space = env.observation_space(params)
    _check_shapes(space, obs)
    assert state.time.shape == () and state.terminated.dtype == jnp.bool_
    if stepped:
        obs2, _, reward, term, trunc, info = out
        _check_shapes(space, obs2)
        assert reward.dtype == jnp.float32 and term.dtype == trunc.dtype == jnp.bool_
        assert info["cost"].dtype == jnp.float32 and info["violation"].dtype == jnp.bool_
    dict_env, _ = jgx.make(env_id, observation="dict")
    want = {"image", "direction"} | ({"constraint"} if env_id in SCENARIOS else set())
    assert set(dict_env.observation_space(params).spaces) == want


def test_one_id_per_level_covers_every_level_class():
    assert len(ONE_ID_PER_LEVEL) < len(jaxgrid.registered_ids()) / 2  # the sample saves
    levels = {type(jaxgrid.make(i)) for i in jaxgrid.registered_ids()}
    assert {type(jaxgrid.make(i)) for i in ONE_ID_PER_LEVEL} == levels


@pytest.mark.slow
@pytest.mark.parametrize("env_id", jaxgrid.registered_ids())
def test_every_id_runs(env_id):
    for observation in jgx.OBSERVATIONS:
        env, params = jgx.make(env_id, observation=observation)
        obs0, inside0, (_, (out, inside)) = _rollout(env, params, 2, _actions(2, (4, 2)))
        assert bool(jnp.all(inside0)) and bool(jnp.all(inside))


# --- errors, imports, older gymnax ------------------------------------------------------------
def test_bad_id_and_observation_raise_before_any_compile(compiles):
    with pytest.raises(ValueError, match="unknown environment id 'MiniGrid-Nope-v0'"):
        jgx.make("MiniGrid-Nope-v0")
    with pytest.raises(ValueError, match=r"observation must be one of \('flat', 'dict'\)"):
        jgx.make("TwoRooms-v0", observation="pixels")
    with pytest.raises(ValueError, match="has no setting 'max_step'"):
        jgx.make("TwoRooms-v0", max_step=5)
    assert compiles == []


def test_jaxgrid_imports_without_gymnax_and_the_adapter_names_the_extra():
    code = (
        "import sys\n"
        "sys.modules['gymnax'] = None  # as if not installed\n"
        "import jaxgrid, jaxgrid.gym\n"
        "try:\n"
        "    import jaxgrid.gymnax\n"
        "except ImportError as e:\n"
        "    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert 'jaxgrid.gymnax needs gymnax: pip install -e ".[gymnax]"' in out.stdout, out


def _legacy_step(self, key, state, action, params=None):
    """gymnax 0.0.8's ``Environment.step``: ``step_env``'s flag ends the episode; 5-tuple."""
    if params is None:
        params = self.default_params
    key, key_reset = jax.random.split(key)
    obs_st, state_st, reward, done, info = self.step_env(key, state, action, params)
    obs_re, state_re = self.reset_env(key_reset, params)
    state = jax.tree.map(lambda x, y: jax.lax.select(done, x, y), state_re, state_st)
    obs = jax.lax.select(done, obs_re, obs_st)
    return obs, state, reward, done, info


def test_gymnax_before_is_truncated_gets_done_with_truncation(monkeypatch):
    monkeypatch.setattr(jgx, "SPLIT_TRUNCATION", False)
    with pytest.raises(ValueError, match='observation="dict" needs a gymnax'):
        jgx.make("MiniGrid-Empty-5x5-v0", observation="dict")
    monkeypatch.setattr(jgx.GymnaxEnv, "step", _legacy_step)
    env, params = jgx.make("MiniGrid-Empty-5x5-v0", max_steps=3)

    @jax.jit
    def left_turns():
        _, state = env.reset(jax.random.PRNGKey(0), params)

        def body(state, k):
            obs, state, reward, done, info = env.step(k, state, jnp.int32(0), params)
            return state, (done, info["terminated"], info["truncated"], state.time)

        return jax.lax.scan(body, state, jax.random.split(jax.random.PRNGKey(1), 7))[1]

    done, term, trunc, time_ = left_turns()
    assert done.tolist() == trunc.tolist() == [False, False, True] * 2 + [False]
    assert not term.any() and time_.tolist() == [1, 2, 0, 1, 2, 0, 1]


# --- trained through the adapter --------------------------------------------------------------
def test_ppo_helper_uses_gymnax_api_only():
    source = pathlib.Path(gymnax_ppo.__file__).read_text()
    modules = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            modules |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            modules.add((node.module or "").split(".")[0])
    assert modules <= {"__future__", "typing", "flax", "jax", "numpy", "optax"}, modules


def test_ppo_through_the_adapter_solves_empty_6x6():
    """PureJaxRL-style PPO (16 envs x 32 steps x 40 updates = 20,480 steps) reaches a mean
    episodic return >= 0.9 (optimum 0.956; a random policy gets about 0.1)."""
    env, params = jgx.make("MiniGrid-Empty-6x6-v0")
    config = gymnax_ppo.Config(num_updates=40)
    start = time.perf_counter()
    train = jax.jit(gymnax_ppo.make_train(env, params, config), compiler_options=CHEAP)
    metrics = jax.device_get(train(jax.random.PRNGKey(0)))
    seconds = time.perf_counter() - start
    first, n_first = gymnax_ppo.mean_return(metrics, slice(0, 4))
    last, n_last = gymnax_ppo.mean_return(metrics, slice(30, 40))
    print(
        f"PPO on Empty-6x6: return {first:.3f} -> {last:.3f} ({n_last} episodes), {seconds:.0f} s"
    )
    assert last >= 0.9 and n_last >= 500, (last, n_last)
