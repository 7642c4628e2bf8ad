"""Helpers to run Farama MiniGrid (the reference) side by side with jaxgrid."""

from __future__ import annotations

import gymnasium as gym
import jax
import numpy as np

from jaxgrid.compat import from_minigrid

# Actions biased towards the ones that change the world (forward/toggle/pickup).
ACTION_PROBS = np.array([0.12, 0.12, 0.34, 0.12, 0.08, 0.18, 0.04])


def make_reference(env_id: str, **kwargs):
    import minigrid  # noqa: F401  (registers the MiniGrid ids)

    return gym.make(env_id, **kwargs).unwrapped


def differential_episode(mg_env, seed: int, num_steps: int, step_fn=None) -> int:
    """Reset ``mg_env`` with ``seed``, convert it, step both with the same biased random actions.

    Returns the number of steps compared; raises ``AssertionError`` with the step, action and
    field at the first mismatch. Stops at the end of the episode.
    """
    obs, _ = mg_env.reset(seed=seed)
    env, state, ts = from_minigrid(mg_env)
    step = step_fn or jax.jit(env.step)
    np.testing.assert_array_equal(np.asarray(ts.observation["image"]), obs["image"])
    rng = np.random.default_rng(seed)
    for t in range(num_steps):
        action = int(rng.choice(7, p=ACTION_PROBS))
        obs, reward, terminated, truncated, _ = mg_env.step(action)
        state, ts = step(state, action)
        where = f"seed {seed} step {t + 1} action {action}"
        np.testing.assert_array_equal(
            np.asarray(ts.observation["image"]), obs["image"], err_msg=f"image, {where}"
        )
        assert int(ts.observation["direction"]) == obs["direction"], f"direction, {where}"
        assert np.isclose(float(ts.reward), reward, atol=1e-6), f"reward, {where}"
        assert bool(ts.terminated) == terminated, f"terminated, {where}"
        assert bool(ts.truncated) == truncated, f"truncated, {where}"
        np.testing.assert_array_equal(
            np.asarray(state.grid), mg_env.grid.encode(), err_msg=f"grid, {where}"
        )
        if terminated or truncated:
            return t + 1
    return num_steps
