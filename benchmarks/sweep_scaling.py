"""Training throughput of one compiled program as the number of agents in it grows.

``python -m benchmarks.sweep_scaling [--agents 1 4 16 64] [--mode shaped]`` builds, for each
agent count N, one program that trains N agents at once (``vmap`` over seeds and a swept
``penalty``, as ``--sweep`` does), each with the same envs per agent, and times ``U`` updates
of it in interleaved rounds (compile timed separately). One JSON line per N: total env
steps/s, steps/s per agent, and the total's ratio to the smallest count's (from one agent:
1.0 means vmapping costs nothing; more, that the agents use the machine better together).
"""

from __future__ import annotations

import argparse
import json
import statistics

import jax
import jax.numpy as jnp
from jax import lax

from agents.config import REWARD_MODES
from agents.timing import compile_ahead, timed
from benchmarks.cli import integer
from benchmarks.train_speed import device_description, make_checker, make_config
from checker.cli import run_main

DEFAULTS = {
    "env": "TwoRooms-v0",
    "num_envs": 128,
    "num_steps": 64,
    "epochs": 4,
    "minibatches": 4,
}  # fmt: skip  (the experiments' PPO sizes)


class Agents:
    """``n`` agents (seeds 0..n-1, penalties spread over [0.5, 1.5]) in one program of
    ``updates`` updates."""

    def __init__(self, n: int, mode: str, updates: int, sizes: dict, checker=None):
        from agents.train import make_learner

        config = make_config(mode, sizes, updates)
        learner = make_learner(config, checker if config.uses_checker else None)
        keys = jnp.stack([jax.random.PRNGKey(s) for s in range(n)])
        hparams = {"penalty": jnp.linspace(0.5, 1.5, n, dtype=jnp.float32)}
        self.runner = jax.block_until_ready(jax.jit(jax.vmap(learner.init))(keys, hparams))
        self.steps = n * updates * config.batch_size

        def run(runner):
            def one(r):
                r, metrics = lax.scan(lambda r, _: learner.update(r), r, None, updates)
                return r, metrics["loss"][-1]

            return jax.vmap(one)(runner)

        self.compiled, self.compile_s = compile_ahead(run, self.runner, donate_argnums=0)

    def run(self) -> float:
        (self.runner, _), dt = timed(self.compiled, self.runner)
        return dt


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(prog="python -m benchmarks.sweep_scaling",
                                description=__doc__.splitlines()[0])  # fmt: skip
    p.add_argument("--agents", type=integer, nargs="+", default=[1, 4, 16, 64],
                   help="agent counts to time (each one program)")  # fmt: skip
    p.add_argument("--mode", default="shaped", choices=REWARD_MODES, help="reward mode")
    p.add_argument("--updates", type=integer, default=2, help="updates per timed call")
    p.add_argument("--repeats", type=integer, default=3, help="interleaved timed rounds")
    p.add_argument("--num-envs", type=integer, default=DEFAULTS["num_envs"],
                   help="envs per agent")  # fmt: skip
    args = p.parse_args(argv)
    for name in ("updates", "repeats", "num_envs"):
        if getattr(args, name) < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if any(n < 1 for n in args.agents):
        p.error(f"--agents must be >= 1, got {args.agents}")
    sizes = {**DEFAULTS, "num_envs": args.num_envs}
    checker = None
    if args.mode in ("checker", "lagrangian", "shield"):
        import jaxgrid

        checker = make_checker(jaxgrid.make(sizes["env"]))
    programs = {n: Agents(n, args.mode, args.updates, sizes, checker) for n in args.agents}
    for prog in programs.values():
        prog.run()  # warm-up
    times = {n: [] for n in programs}
    for _ in range(args.repeats):  # interleaved: a load change hits every count alike
        for n, prog in programs.items():
            times[n].append(prog.run())
    first = min(programs)
    base = programs[first].steps / statistics.median(times[first])
    lines = []
    for n, prog in programs.items():
        sps = prog.steps / statistics.median(times[n])
        line = {"agents": n, "mode": args.mode, "envs_per_agent": args.num_envs,
                "sps_total": round(sps, 1), "sps_per_agent": round(sps / n, 1),
                f"total_vs_{first}_agents": round(sps / base, 3),
                "compile_s": round(prog.compile_s, 2), "device": device_description()}  # fmt: skip
        print(json.dumps(line), flush=True)
        lines.append(line)
    return lines


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.sweep_scaling")
