"""Compile options for test-only programs (``jax.jit(..., compiler_options=...)``).

The suite is dominated by XLA compile time on 2 CPU cores. Both option sets only choose how
the same HLO becomes machine code: a program's semantics are unchanged, though floating-point
results may differ in the last bits from another setting's.

* ``CHEAP``: LLVM's optimisations off and XLA:CPU's per-op emitters instead of its fusion
  emitters: 2-5x less compile time than the suite's default (``tests/conftest.py``) for the
  environment programs the tests build, which run briefly. The emitter option is left out
  where this XLA does not know it.
* ``OPTIMISED``: full optimisation, for programs that run long (thousands of episodes, a BFS
  per step), which then take less time in all than cheaply compiled ones.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp

OPTIMISED = {"xla_backend_optimization_level": 3}


def _cheap() -> dict:
    options = {"xla_backend_optimization_level": 0, "xla_cpu_use_fusion_emitters": False}
    try:
        jax.jit(lambda x: x + 1, compiler_options=options).lower(1).compile()
    except Exception:  # an XLA without the option: keep the one every XLA knows
        del options["xla_cpu_use_fusion_emitters"]
    return options


CHEAP = _cheap()


# ``env`` goes in as a pytree argument (its static configuration in the tree's structure), so
# every test of a process that resets or steps an equal env reuses one compiled program,
# where ``jax.jit(env.reset)`` would compile again for each new bound method. Eager calls
# dispatch every operation on its own: 2-3x slower than one cheap compile.
batch_reset = jax.jit(lambda env, keys: jax.vmap(env.reset)(keys), compiler_options=CHEAP)
batch_step = jax.jit(
    lambda env, states, actions: jax.vmap(env.step)(states, actions), compiler_options=CHEAP
)


def compile_seconds(env, num_envs: int) -> tuple[float, float, float]:
    """``(reset compile, reset run, step compile)`` seconds of ``jit(vmap(reset))`` and
    ``jit(vmap(step))`` over ``num_envs`` envs (the suite's XLA flags); prints them."""
    keys = jax.random.split(jax.random.PRNGKey(0), num_envs)
    t0 = time.perf_counter()
    reset = jax.jit(jax.vmap(env.reset)).lower(keys).compile()
    t1 = time.perf_counter()
    states, _ = jax.block_until_ready(reset(keys))
    t2 = time.perf_counter()
    jax.jit(jax.vmap(env.step)).lower(states, jnp.zeros(num_envs, jnp.int32)).compile()
    t3 = time.perf_counter()
    print(f"compile reset {t1 - t0:.2f} s, step {t3 - t2:.2f} s; {num_envs} resets {t2 - t1:.3f} s")
    return t1 - t0, t2 - t1, t3 - t2
