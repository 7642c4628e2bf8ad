"""jaxgrid.gym: registration, gymnasium's env checker, and the vector env == vmap(AutoReset)."""

from __future__ import annotations

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode
from helpers.xla import CHEAP

import jaxgrid
import jaxgrid.gym as jgym
from jaxgrid.wrappers import AutoReset

NUM_ENVS = 64  # the examples' batch size too, so the compiled step is shared


def test_every_id_registered_idempotently():
    ids = {f"jaxgrid/{i}" for i in jaxgrid.registered_ids()}
    assert ids <= set(gym.registry)
    assert jgym.register_envs() == []  # a second call adds nothing


@pytest.mark.parametrize("env_id", ["TwoRooms-v0", "MiniGrid-DoorKey-5x5-v0"])
def test_check_env(env_id, recwarn):
    env = gym.make(f"jaxgrid/{env_id}", render_mode="rgb_array")
    check_env(env.unwrapped)  # also makes and checks every declared render mode
    messages = [str(w.message) for w in recwarn.list if "gymnasium" in str(w.filename)]
    assert not messages, messages
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.shape[2] == 3
    env.close()


def test_single_env_matches_jax_env():
    env = gym.make("jaxgrid/TwoRooms-v0", render_mode="ansi")
    obs, info = env.reset(seed=7)
    jenv = env.unwrapped.jax_env
    state = env.unwrapped.state
    assert set(info) == {"violation", "cost", "constraint_type", "template_id"}
    assert isinstance(info["violation"], np.bool_)
    rng = np.random.default_rng(0)
    for _ in range(30):
        a = int(rng.integers(7))
        obs, reward, term, trunc, info = env.step(a)
        state, ts = jenv.step(state, a)
        np.testing.assert_array_equal(obs["image"], ts.observation["image"])
        np.testing.assert_array_equal(obs["constraint"], ts.observation["constraint"])
        assert obs["direction"] == int(ts.observation["direction"])
        assert reward == float(ts.reward) and term == bool(ts.terminated)
        if term or trunc:
            break
    assert any(arrow in env.render() for arrow in (">>", "VV", "<<", "^^"))


@pytest.mark.parametrize("env_id", ["TwoRooms-v0"])
def test_vector_env_equals_vmapped_autoreset(env_id):
    envs = gym.make_vec(f"jaxgrid/{env_id}", num_envs=NUM_ENVS)
    assert isinstance(envs, jgym.JaxGridVectorEnv)
    assert envs.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    ref = AutoReset(jaxgrid.make(env_id, max_steps=20))
    envs = jgym.JaxGridVectorEnv(env_id, NUM_ENVS, max_steps=20)  # short episodes: many resets

    obs, infos = envs.reset(seed=3)
    reset = jax.jit(jax.vmap(ref.reset), compiler_options=CHEAP)
    states, ts = reset(jax.random.split(jax.random.PRNGKey(3), NUM_ENVS))
    step = jax.jit(jax.vmap(ref.step), compiler_options=CHEAP)
    for k in ts.observation:
        np.testing.assert_array_equal(obs[k], ts.observation[k])
    assert envs.observation_space.contains(obs)
    rng = np.random.default_rng(0)
    resets = 0
    for t in range(60):
        actions = rng.integers(0, 7, NUM_ENVS)
        obs, rew, term, trunc, infos = envs.step(actions)
        states, ts = step(states, jnp.asarray(actions, jnp.int32))
        for k in ts.observation:
            np.testing.assert_array_equal(obs[k], ts.observation[k], err_msg=f"{k} at step {t}")
        np.testing.assert_array_equal(rew, ts.reward)
        np.testing.assert_array_equal(term, ts.terminated)
        np.testing.assert_array_equal(trunc, ts.truncated)
        np.testing.assert_array_equal(infos["violation"], ts.info["violation"])
        done = np.asarray(ts.terminated | ts.truncated)
        if done.any():
            resets += int(done.sum())
            np.testing.assert_array_equal(infos["_final_obs"], done)
            i = int(np.flatnonzero(done)[0])
            np.testing.assert_array_equal(
                infos["final_obs"][i]["image"], ts.info["final_observation"]["image"][i]
            )
            if (~done).any():
                assert infos["final_obs"][int(np.flatnonzero(~done)[0])] is None
    assert resets > NUM_ENVS  # auto-reset was exercised
    with pytest.warns(UserWarning, match="without specifying any render mode"):
        assert envs.render() is None  # no render mode: gymnasium's warning, no frames
    envs.close()
