"""Shared cases of the PPO learner's tests (``tests/agents/``): the tiny configurations, a
small checker configuration, and a counter of XLA compilations.

Configurations are tiny (8 envs x 8 steps, 4 updates in 2 chunks of 2, one epoch of 2
minibatches) so that the tests run on 2 CPU cores. Programs built only for the tests compile
with LLVM's optimisations off (``fast_jit``): about half the compile time, same semantics.
"""

from __future__ import annotations

import contextlib
import functools

import jax
import jax.numpy as jnp
import numpy as np

from agents.config import PPOConfig
from checker.model import CheckerConfig

TINY = PPOConfig(
    num_envs=8, num_steps=8, total_timesteps=8 * 8 * 4, update_epochs=1, num_minibatches=2,
    eval_every=2, eval_episodes=4, penalty_start=0.0, penalty_warmup=0.0, novelty_bonus=0.0,
    film_codes=False, alarm_forward=False,
)  # fmt: skip
# A small checker (window of 3 frames) with the scenarios' 5x5 view.
CHECKER_CONFIG = CheckerConfig(
    window=3, word_dim=8, gru_dim=16, state_dim=16, cell_dim=4, conv_channels=4,
    temporal_channels=8, mlp_dim=16, mlp_layers=1,
)  # fmt: skip
SEEDS = (0, 1)
FAST = {"xla_backend_optimization_level": 0}
fast_jit = functools.partial(jax.jit, compiler_options=FAST)

# The event jax records once per XLA backend compilation (``jax._src.dispatch.
# BACKEND_COMPILE_EVENT``), with the compiled function's name as ``fun_name``.
BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


def keys_of(*seeds):
    return jnp.stack([jax.random.PRNGKey(s) for s in seeds])


def leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(tree)]


@contextlib.contextmanager
def count_compiles():
    """Collect the names of the programs XLA compiles inside the block (a list).

    Counts every backend compilation of the process, eager operations included, through the
    public ``jax.monitoring`` listeners.
    """
    names: list[str] = []

    def listener(event, duration, **kwargs):
        if event == BACKEND_COMPILE_EVENT:
            names.append(str(kwargs.get("fun_name", "?")))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


def assert_counter_sees_compiles() -> None:
    """Guard for tests asserting zero compilations: the counter does see a fresh program."""
    with count_compiles() as names:
        fast_jit(lambda x: x + 1)(np.arange(3))
    assert names == ["jit(<lambda>)"], names
