"""Several training programs at once, in threads, against the same programs one after the other.

``python -m benchmarks.threads [--experiment two_rooms] [--modes none shaped] [--seeds 5]
[--updates 8] [--rounds 3]`` builds one program per reward mode with the experiment's
configuration (``seeds`` agents vmapped, as it trains a mode), compiles them ahead, and in
each round runs every program for 2 calls of ``updates`` updates one after the other, then
all of them at once in one thread each (the experiments' ``--workers``). One JSON line: the
seconds of each round both ways, the speed-up (one after the other / at once; median over
rounds) and whether the parameters at once were identical to the bit to those one after the
other. The checker modes use a freshly initialised checker of the experiment's kind (the
speed does not depend on its weights).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import threading
import time

import jax
import numpy as np
from jax import lax

from agents.config import REWARD_MODES, PPOConfig
from agents.timing import compile_ahead
from benchmarks.cli import integer
from benchmarks.train_speed import device_description, make_checker
from checker.cli import run_main

CALLS = 2  # calls of the compiled program per run and round
EXPERIMENTS = ("two_rooms", "two_rooms_lava", "three_rooms_key", "hazard_rooms")


def _scenario(experiment: str):
    """The default preset of ``experiments.<experiment>``."""
    import importlib

    from experiments.pipeline import preset

    return preset(importlib.import_module(f"experiments.{experiment}").SCENARIO)


def _program(ppo: PPOConfig, mode: str, seeds: int, updates: int, checker):
    """``(compiled scan of updates, runner)`` of ``seeds`` agents of ``ppo`` in ``mode``."""
    from agents.train import make_learner

    config = dataclasses.replace(ppo, reward_mode=mode)
    learner = make_learner(config, checker if config.uses_checker else None)
    runner = jax.jit(jax.vmap(learner.init))(jax.random.split(jax.random.PRNGKey(0), seeds))

    def scan(r):
        return lax.scan(lambda r, _: (learner.update(r)[0], None), r, None, length=updates)[0]

    compiled, _ = compile_ahead(jax.vmap(scan), runner)
    return compiled, jax.block_until_ready(compiled(runner))  # warm


def _train(program, out: dict, name: str) -> None:
    compiled, runner = program
    for _ in range(CALLS):
        runner = compiled(runner)
    out[name] = jax.block_until_ready(runner)


def _params(runner) -> list[np.ndarray]:
    return [np.asarray(x) for x in jax.tree.leaves(runner.params)]


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.threads", description=__doc__)
    p.add_argument("--experiment", default="two_rooms", choices=EXPERIMENTS)
    p.add_argument("--modes", nargs="+", default=["none", "shaped"], choices=REWARD_MODES)
    p.add_argument("--seeds", type=integer, default=5, help="agents per program (vmapped)")
    p.add_argument("--updates", type=integer, default=8, help="updates per call")
    p.add_argument("--rounds", type=integer, default=3)
    args = p.parse_args(argv)
    for name in ("seeds", "updates", "rounds"):
        if getattr(args, name) < 1:
            p.error(f"--{name} must be >= 1, got {getattr(args, name)}")
    if len(set(args.modes)) < 2:
        p.error("--modes: name at least two different modes")
    scenario = _scenario(args.experiment)
    checker = None
    if any(PPOConfig(reward_mode=m).uses_checker for m in args.modes):
        checker = make_checker(scenario.ppo.make_env(), scenario.checker_kind)
    programs = {m: _program(scenario.ppo, m, args.seeds, args.updates, checker)
                for m in args.modes}  # fmt: skip
    sequential, threaded, identical = [], [], True
    for _ in range(args.rounds):
        alone, together = {}, {}
        start = time.perf_counter()
        for m in args.modes:
            _train(programs[m], alone, m)
        sequential.append(time.perf_counter() - start)
        threads = [threading.Thread(target=_train, args=(programs[m], together, m))
                   for m in args.modes]  # fmt: skip
        start = time.perf_counter()
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        threaded.append(time.perf_counter() - start)
        identical &= all(
            all(np.array_equal(a, b) for a, b in zip(_params(alone[m]), _params(together[m]),
                                                    strict=True))
            for m in args.modes
        )  # fmt: skip
    steps = len(args.modes) * CALLS * args.updates * args.seeds * scenario.ppo.batch_size
    line = {
        "experiment": args.experiment, "modes": args.modes, "seeds": args.seeds,
        "updates_per_call": args.updates,
        "calls": CALLS, "rounds": args.rounds, "device": device_description(),
        "sequential_s": [round(s, 2) for s in sequential],
        "threads_s": [round(s, 2) for s in threaded],
        "sps_sequential": round(steps / statistics.median(sequential)),
        "sps_threads": round(steps / statistics.median(threaded)),
        "speedup": round(statistics.median(s / t for s, t in zip(sequential, threaded,
                                                                   strict=True)), 3),
        "identical": bool(identical),
    }  # fmt: skip
    print(json.dumps(line), flush=True)
    return line


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.threads")
