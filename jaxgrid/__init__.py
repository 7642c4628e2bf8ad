"""jaxgrid: MiniGrid-exact grid worlds in pure JAX.

>>> import jax, jaxgrid
>>> env = jaxgrid.make("MiniGrid-DoorKey-8x8-v0")
>>> state, ts = env.reset(jax.random.PRNGKey(0))
>>> state, ts = env.step(state, 2)  # forward
"""

from jaxgrid import constants, render, video, wrappers  # render/video: cheap, no side effects
from jaxgrid.ascii import from_ascii
from jaxgrid.environment import Environment
from jaxgrid.registry import make, register, registered_ids
from jaxgrid.types import State, TimeStep

__all__ = [
    "Environment",
    "State",
    "TimeStep",
    "constants",
    "from_ascii",
    "make",
    "register",
    "registered_ids",
    "render",
    "video",
    "wrappers",
]
__version__ = "0.1.0"
