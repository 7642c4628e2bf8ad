"""jaxgrid: MiniGrid-exact grid worlds in pure JAX.

>>> import jax, jaxgrid
>>> env = jaxgrid.make("MiniGrid-DoorKey-8x8-v0")
>>> state, ts = env.reset(jax.random.PRNGKey(0))
>>> state, ts = env.step(state, 2)  # forward

The names below load on first use (PEP 562), so that ``import jaxgrid.rundir`` (standard
library only) costs milliseconds and a command can handle Ctrl-C before jax loads.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # what the names are, for readers and static tools
    from jaxgrid import constants, render, video, wrappers
    from jaxgrid.ascii import from_ascii
    from jaxgrid.environment import Environment
    from jaxgrid.registry import make, register, registered_ids
    from jaxgrid.types import State, TimeStep

# name -> the module that defines it
_NAMES = {
    "Environment": "jaxgrid.environment",
    "State": "jaxgrid.types",
    "TimeStep": "jaxgrid.types",
    "from_ascii": "jaxgrid.ascii",
    "make": "jaxgrid.registry",
    "register": "jaxgrid.registry",
    "registered_ids": "jaxgrid.registry",
}

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


def __getattr__(name: str):
    """``jaxgrid.make`` and the other names, and any submodule (``jaxgrid.language``)."""
    if name in _NAMES:
        value = getattr(importlib.import_module(_NAMES[name]), name)
        globals()[name] = value
        return value
    try:
        return importlib.import_module(f"jaxgrid.{name}")
    except ModuleNotFoundError as e:
        if e.name != f"jaxgrid.{name}":
            raise
    raise AttributeError(f"module 'jaxgrid' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
