"""Compile time per MiniGrid id: ``jit(vmap(reset))`` and the auto-resetting ``jit(vmap(step))``.

For each natively generated MiniGrid id (or ``--ids``), with ``--num-envs`` envs: the seconds
to lower and compile the batched reset, and the batched ``AutoReset`` step (the program a
training loop runs: the level's step plus a fresh layout for every env that ended), each with
a fresh cache. An id *passes* when the two together take at most ``--budget`` seconds (5 by
default). With ``--repeats k`` every id is timed in ``k`` passes over the ids and each program's
fastest compile counts: other processes on a shared machine only ever add time, and a burst of
them lands on different ids in different passes. XLA's own flags are left as they are.
Usage::

    python -m benchmarks.compile_times                         # every id, ~5 min on 2 cores
    python -m benchmarks.compile_times --repeats 3             # the published figures
    python -m benchmarks.compile_times --ids MiniGrid-ObstructedMaze-Full-v0 --num-envs 4096
"""

from __future__ import annotations

import argparse
import platform
import sys

import jax
import jax.numpy as jnp

from agents.timing import compile_ahead
from benchmarks.cli import integer, real
from benchmarks.layout_fidelity import native_ids
from checker.cli import run_main
from jaxgrid.io import write_json
from jaxgrid.registry import make
from jaxgrid.wrappers import AutoReset


def compile_seconds(env_id: str, num_envs: int) -> dict:
    """``{"reset_s", "step_s", "total_s"}`` for ``env_id`` at ``num_envs`` envs, each program
    compiled from an empty cache, as in a fresh process."""
    env = AutoReset(make(env_id))
    keys = jax.random.split(jax.random.PRNGKey(0), num_envs)
    jax.clear_caches()
    reset, reset_s = compile_ahead(jax.vmap(env.reset), keys)
    states, _ = reset(keys)
    actions = jnp.zeros(num_envs, jnp.int32)
    _, step_s = compile_ahead(jax.vmap(env.step), states, actions)
    return {"reset_s": reset_s, "step_s": step_s, "total_s": reset_s + step_s}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.compile_times",
                                     description=__doc__.split("\n\n")[0])  # fmt: skip
    parser.add_argument("--ids", nargs="*", default=None, help="ids to time (default: all)")
    parser.add_argument("--num-envs", type=integer, default=64, help="envs per batch")
    parser.add_argument("--budget", type=real, default=5.0, help="seconds allowed per id")
    parser.add_argument("--repeats", type=integer, default=1, help="compiles per program (fastest)")
    parser.add_argument("--json", default=None, help="write the report here")
    args = parser.parse_args(argv)
    if args.num_envs < 1:
        parser.error(f"--num-envs must be at least 1, got {args.num_envs}")
    if args.repeats < 1:
        parser.error(f"--repeats must be at least 1, got {args.repeats}")
    if args.budget <= 0:
        parser.error(f"--budget must be positive, got {args.budget}")
    ids = args.ids or native_ids()
    unknown = [i for i in ids if i not in native_ids()]
    if unknown:
        parser.error(f"not a native MiniGrid id: {unknown[0]!r}; ids: {', '.join(native_ids())}")
    device = jax.devices()[0]
    report = {
        "device": f"{device.platform}: {getattr(device, 'device_kind', '')} "
        f"({platform.processor() or platform.machine()})",
        "jax": jax.__version__,
        "num_envs": args.num_envs,
        "budget_s": args.budget,
        "repeats": args.repeats,
        "ids": {},
    }
    for rep in range(args.repeats):
        for k, env_id in enumerate(ids):
            r = compile_seconds(env_id, args.num_envs)
            best = report["ids"].setdefault(env_id, r)
            best["reset_s"] = min(best["reset_s"], r["reset_s"])
            best["step_s"] = min(best["step_s"], r["step_s"])
            best["total_s"] = best["reset_s"] + best["step_s"]
            best["passed"] = best["total_s"] <= args.budget
            print(
                f"[pass {rep + 1}/{args.repeats}, {k + 1}/{len(ids)}] {env_id}: reset "
                f"{r['reset_s']:.2f} s + step {r['step_s']:.2f} s = {r['total_s']:.2f} s",
                file=sys.stderr,
            )
    totals = {i: r["total_s"] for i, r in report["ids"].items()}
    slowest = max(totals, key=totals.get)
    report["failed"] = [i for i, r in report["ids"].items() if not r["passed"]]
    report["slowest"] = {"id": slowest, "total_s": totals[slowest]}
    print(f"\n{len(ids) - len(report['failed'])}/{len(ids)} ids compile within {args.budget} s")
    print(f"slowest: {slowest} {totals[slowest]:.2f} s; over budget: {report['failed'] or 'none'}")
    if args.json:
        write_json(args.json, report)
    return report


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.compile_times")
