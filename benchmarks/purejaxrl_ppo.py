"""PureJaxRL-style PPO baseline: training throughput on NAVIX DoorKey-8x8.

The learner is :mod:`agents.baseline` (PureJaxRL's ``ppo_minigrid`` re-implemented, on
``Navix-DoorKey-8x8-v0`` by default, or on any jaxgrid id with ``--env``); this command
compiles it, times one run and prints the figures.

Usage::

    python -m benchmarks.purejaxrl_ppo --timesteps 2000000
    # -> one JSON line {"impl": "purejaxrl-navix", "env": ..., "sps": ..., ...}

The machine is shared; quote throughput ratios measured back to back, not absolutes.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from agents.baseline import DEFAULT_CONFIG, DEFAULT_ENV, impl_name, measure
from benchmarks.cli import integer, require
from checker.cli import run_main


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.purejaxrl_ppo",
        description=__doc__.splitlines()[0],
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    c = DEFAULT_CONFIG
    parser.add_argument(
        "--timesteps",
        type=integer,
        default=c["TOTAL_TIMESTEPS"],
        help="env steps to train for, rounded down to whole updates",
    )
    parser.add_argument("--num-envs", type=integer, default=c["NUM_ENVS"], help="parallel envs")
    parser.add_argument(
        "--num-steps", type=integer, default=c["NUM_STEPS"], help="rollout length per update"
    )
    parser.add_argument(
        "--update-epochs", type=integer, default=c["UPDATE_EPOCHS"], help="epochs over each batch"
    )
    parser.add_argument(
        "--num-minibatches",
        type=integer,
        default=c["NUM_MINIBATCHES"],
        help="minibatches per epoch",
    )
    parser.add_argument("--seed", type=integer, default=0, help="PRNG seed of the run")
    parser.add_argument(
        "--env",
        default=DEFAULT_ENV,
        help="a Navix-* id (PureJaxRL's setting) or a jaxgrid id, e.g. "
        "MiniGrid-DoorKey-8x8-v0 (the same learner on jaxgrid)",
    )
    args = parser.parse_args(argv)
    if not args.env.startswith("Navix-"):
        import jaxgrid

        if args.env not in jaxgrid.registered_ids():
            parser.error(f"--env {args.env!r} is neither a Navix-* id nor a jaxgrid id")
    for name in ("timesteps", "num_envs", "num_steps", "update_epochs", "num_minibatches"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    batch = args.num_envs * args.num_steps
    if args.timesteps < batch:
        parser.error(
            f"--timesteps ({args.timesteps}) must cover one update of --num-envs x "
            f"--num-steps ({batch}) env steps"
        )
    if batch % args.num_minibatches:
        parser.error(
            f"--num-minibatches ({args.num_minibatches}) must divide --num-envs x "
            f"--num-steps ({batch})"
        )
    if args.env.startswith("Navix-"):
        require(
            "navix",
            f"--env {args.env}",
            instead="pass --env MiniGrid-DoorKey-8x8-v0 (the same learner on jaxgrid)",
        )
    res = measure(
        total_timesteps=args.timesteps,
        num_envs=args.num_envs,
        num_steps=args.num_steps,
        update_epochs=args.update_epochs,
        num_minibatches=args.num_minibatches,
        seed=args.seed,
        env_name=args.env,
    )
    line = {
        "impl": impl_name(args.env),
        "env": args.env,
        "sps": round(res["sps"], 1),
        "compile_s": round(res["compile_s"], 2),
        "device": res["device"],
        "timesteps": res["total_timesteps"],
    }
    print(json.dumps(line), flush=True)
    return line


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.purejaxrl_ppo")
