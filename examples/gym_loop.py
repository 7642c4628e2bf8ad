"""Gymnasium loops over jaxgrid: one environment, then a batch stepped in one jitted call.

python examples/gym_loop.py
"""

import gymnasium as gym
import numpy as np

import jaxgrid.gym  # noqa: F401  (registers the "jaxgrid/..." ids)
from jaxgrid.language import detokenize

env = gym.make("jaxgrid/TwoRooms-v0", render_mode="ansi")
obs, info = env.reset(seed=0)
print(env.render())
print("constraint:", detokenize(obs["constraint"]))
episode_return, violations = 0.0, 0
for _ in range(200):
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
    episode_return += reward
    violations += int(info["violation"])
    if terminated or truncated:
        print(f"episode over: return {episode_return:.2f}, violations {violations}")
        obs, info = env.reset()
        episode_return, violations = 0.0, 0
env.close()

envs = gym.make_vec("jaxgrid/TwoRooms-v0", num_envs=64)  # one jitted vmapped step
obs, infos = envs.reset(seed=0)
ended = 0
for _ in range(100):
    obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())
    ended += int(np.sum(terminations | truncations))  # those envs already restarted
print(f"batch of images {obs['image'].shape}; {ended} episodes ended in 100 steps")
envs.close()
