"""Scheduling of an experiment's phases: which run when, in which thread.

- :class:`Workers`: the phases that train (the checker's chain, each reward mode), ``n`` at
  once in threads, stopped together.
- :class:`Compiler`: the modes' programs compiled in one background thread meanwhile, the
  slowest to train first (:data:`TRAINING_COST`).

The phases themselves are :mod:`experiments.phases`; :func:`experiments.pipeline.run_experiment`
hands them to these.
"""

from __future__ import annotations

import threading
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from pathlib import Path

from agents.programs import precompile
from experiments.phases import mode_arguments

__all__ = ["TRAINING_COST", "Compiler", "Workers"]

# Seconds per update of each mode relative to ``none`` (TwoRooms, benchmarks.train_speed; the
# constrained baselines from their time against lagrangian's): modes are compiled and started
# slowest first, so that the last to finish is a short one.
TRAINING_COST = {"cpo": 3.8, "shield": 1.9, "checker": 1.2, "saute": 1.19, "focops": 1.16,
                 "lagrangian": 1.15, "pid_lagrangian": 1.13, "shaped": 1.0, "none": 1.0,
                 "shield_monitor": 0.97}  # fmt: skip


class Workers:
    """Runs the phases that train, ``n`` at once, in threads.

    Each phase is its own compiled program, and XLA releases the GIL while one runs. The
    kernels of both run on XLA's CPU thread pool, which one PPO program leaves idle part of
    the time (many small, dependent kernels): on 2 cores two reward modes trained at once
    finished 1.2x (TwoRooms) to 1.4x (HazardRooms) sooner than one after the other, with
    bit-identical results (``python -m benchmarks.threads``, ``docs/decisions.md``); three
    at once gained less. ``n`` 1 runs them one after the other. :meth:`close` sets
    :attr:`cancel`, which every run checks before each chunk.
    """

    def __init__(self, n: int):
        self.cancel = threading.Event()
        self.pool = ThreadPoolExecutor(n, thread_name_prefix="train")

    def submit(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs)`` in a free thread: a ``concurrent.futures.Future``."""
        return self.pool.submit(fn, *args, **kwargs)

    @staticmethod
    def results(jobs: dict) -> dict:
        """``{name: future}`` -> ``{name: result}``; the first failure is raised as soon as
        it happens, not when its turn comes."""
        done, _ = wait(jobs.values(), return_when=FIRST_EXCEPTION)
        for job in done:
            if not job.cancelled() and job.exception() is not None:
                raise job.exception()
        return {name: job.result() for name, job in jobs.items()}

    def close(self, wait: bool = True) -> None:
        """Stop the threads at their next chunk; ``wait`` for them (Ctrl-C does not: a
        command then leaves at once through :func:`jaxgrid.rundir.exit_now`, which waits
        only for a checkpoint being written)."""
        self.cancel.set()
        self.pool.shutdown(wait=wait, cancel_futures=True)


class Compiler:
    """Compiles the agents' programs in one background thread while the main thread works.

    XLA's compiler releases the GIL, so the modes' programs compile on the second core while
    the first trains the behaviour agent, the checker or another mode: ``--quick`` is mostly
    compile time. :meth:`submit` queues the modes without a checker (before it is trained)
    or those with one; :meth:`wait` before a mode trains: it waits for that mode's programs,
    or takes the job back if the thread has not started it (the run then compiles them).
    A mode whose run directory holds its last checkpoint gets only its final evaluation
    compiled: resuming a finished run retrains nothing.
    """

    def __init__(self, cfg):
        self.cfg, self.jobs = cfg, {}
        self.order: list[str] = []  # the modes in the order they were queued
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="compile")

    def submit(self, checkers: dict | None = None) -> None:
        """Queue the modes that need no checker (``checkers`` None) or those that need one,
        each with its checker in ``checkers`` ({mode: trained checker}), the slowest to
        train first (:data:`TRAINING_COST`)."""
        for mode in sorted(self.cfg.modes, key=lambda m: -TRAINING_COST.get(m, 1.0)):
            config, checker, common = mode_arguments(self.cfg, mode, (checkers or {}).get(mode))
            if mode not in self.jobs and config.uses_checker == (checkers is not None):
                out_dir = Path(self.cfg.out) / "modes" / mode  # finished: the final only
                self.jobs[mode] = self.pool.submit(precompile, config, checker, **common,
                                                   out_dir=out_dir)  # fmt: skip
                self.order.append(mode)

    def wait(self, mode: str) -> None:
        job = self.jobs.pop(mode, None)
        if job is not None and not job.cancel():
            job.result()

    def close(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)
