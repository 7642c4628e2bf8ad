"""Where :func:`agents.runner.run`'s arrays live: the device mesh that splits the environment
batch, the shardings of the runner state over it, and results brought back to the host.

With more than one device, the environment batch (every leaf of
:class:`agents.rollout.EnvCarry`) is sharded along its env axis over a 1-D
``jax.sharding.Mesh`` named ``"envs"``; parameters, optimiser state and keys are replicated.
XLA partitions the rollout and inserts the collectives of the minibatch shuffle. For several
hosts, call ``jax.distributed.initialize()`` in every process before ``run``: the mesh is
then built over ``jax.devices()`` (all hosts) instead of the local ones (``multi_host=True``).
Every process calls ``run`` with the same arguments and gets the same records and
(replicated) parameters, the same numbers as one process with as many devices; process 0
alone writes ``out_dir``'s logs (a directory all hosts share) and shows progress. The
returned ``runner``'s env leaves stay split over the processes
(``jax.experimental.multihost_utils.process_allgather`` gathers them, as :func:`to_host`
does).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from agents.train import RunnerState

__all__ = ["devices", "mesh", "shardings", "to_host"]


def devices(multi_host: bool = False) -> list:
    """The devices a run spreads over: every process's (``multi_host``), else this one's."""
    return jax.devices() if multi_host else jax.local_devices()


def mesh(num_envs: int, multi_host: bool = False) -> Mesh | None:
    """The 1-D ``"envs"`` mesh over :func:`devices`, ``None`` on one device; a ``ValueError``
    (before anything compiles) if ``num_envs`` does not split evenly over them."""
    found = devices(multi_host)
    if len(found) == 1:
        return None
    if num_envs % len(found):
        raise ValueError(
            f"PPOConfig.num_envs ({num_envs}) must be divisible by the number of devices "
            f"({len(found)}) to shard the environment batch"
        )
    return Mesh(np.asarray(found), ("envs",))


def shardings(runner: RunnerState, mesh: Mesh) -> RunnerState:
    """The sharding of each leaf of a seed-stacked ``runner``: env leaves split on axis 1
    (axis 0 is the seed axis) over ``mesh``; everything else replicated."""
    replicated = NamedSharding(mesh, PartitionSpec())
    split = NamedSharding(mesh, PartitionSpec(None, "envs"))
    # Every field but the env batch is replicated, a mode's own state (the PID's) included.
    everywhere = jax.tree.map(lambda _: replicated, runner)
    return everywhere.replace(env=jax.tree.map(lambda _: split, runner.env))


def to_host(x) -> Any:
    """``x`` as numpy arrays. An array split over several processes is gathered from all of
    them: a collective, which every process reaches in the same order (same program)."""

    def get(a):
        if isinstance(a, jax.Array) and not (a.is_fully_addressable or a.is_fully_replicated):
            return np.asarray(multihost_utils.process_allgather(a, tiled=True))
        return np.asarray(a)

    return jax.tree.map(get, x)
