"""Render a TwoRooms episode (a random policy) to ``two_rooms.gif``, captioned with the
constraint, step, reward and violations.

    python examples/render_gif.py
"""

import jax

import jaxgrid
from jaxgrid.video import record_episodes


def policy(obs, state, key):
    """Uniformly random among left, right, forward and toggle (doors start closed)."""
    return jax.random.choice(key, jax.numpy.array([0, 1, 2, 5]))


env = jaxgrid.make("TwoRooms-v0")
frames = record_episodes(
    env, policy, jax.random.PRNGKey(0), num_episodes=2, path="two_rooms.gif", max_steps=40
)
print(f"wrote two_rooms.gif: {frames.shape[0]} frames of {frames.shape[2]}x{frames.shape[1]}")
