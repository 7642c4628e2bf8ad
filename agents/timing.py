"""Compile-then-time, the one timing protocol of the machine baseline
(:func:`agents.baseline.machine_baseline`) and of every benchmark in ``benchmarks``.

A jitted function is lowered and compiled ahead (:func:`compile_ahead`, timed on its own, so
compile time never leaks into a throughput figure), then called with each call closed by
``jax.block_until_ready`` (:func:`timed`), since JAX dispatches asynchronously and a call
returns before its work is done. :func:`measure` does both with repeated calls on the same
arguments; benchmarks that thread state through calls (a donated runner state) or interleave
several programs use the two pieces directly.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from collections.abc import Callable
from typing import Any

import jax

__all__ = ["Timing", "compile_ahead", "measure", "timed"]


def compile_ahead(fn: Callable, *args: Any, **jit_kwargs: Any) -> tuple[Callable, float]:
    """``(jax.jit(fn, **jit_kwargs).lower(*args).compile(), seconds it took)``.

    ``fn`` may already be jitted (then ``jit_kwargs`` must be empty). The executable accepts
    only arguments of the shapes and dtypes of ``args``.
    """
    if not hasattr(fn, "lower"):
        fn = jax.jit(fn, **jit_kwargs)
    elif jit_kwargs:
        raise ValueError(f"fn is already jitted; jit options {sorted(jit_kwargs)} do not apply")
    t0 = time.perf_counter()
    compiled = fn.lower(*args).compile()
    return compiled, time.perf_counter() - t0


def timed(fn: Callable, *args: Any) -> tuple[Any, float]:
    """``(fn(*args), seconds until its result is ready)`` (``jax.block_until_ready``)."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    return out, time.perf_counter() - t0


@dataclasses.dataclass(frozen=True)
class Timing:
    """Compile seconds, the seconds of each timed call, and the last call's output."""

    compile_s: float
    times_s: tuple[float, ...]
    output: Any = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def median_s(self) -> float:
        return float(statistics.median(self.times_s))

    @property
    def best_s(self) -> float:
        return float(min(self.times_s))

    def rate(self, work: float) -> float:
        """``work`` (e.g. env steps per call) per second of the median call."""
        return work / self.median_s


def measure(fn: Callable, *args: Any, repeats: int = 3, **jit_kwargs: Any) -> Timing:
    """Compile ``fn`` for ``args`` ahead (timed), then time ``repeats`` calls on ``args``.

    Arguments must not be donated (every call reuses them).
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    if jit_kwargs.get("donate_argnums") or jit_kwargs.get("donate_argnames"):
        raise ValueError("measure calls fn on the same arguments each time: do not donate them")
    compiled, compile_s = compile_ahead(fn, *args, **jit_kwargs)
    times, out = [], None
    for _ in range(repeats):
        out, dt = timed(compiled, *args)
        times.append(dt)
    return Timing(compile_s, tuple(times), out)
