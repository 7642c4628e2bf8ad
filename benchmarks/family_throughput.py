"""Env throughput per MiniGrid family: jaxgrid against NAVIX on each family both ship.

The harness of :mod:`benchmarks.env_throughput` (random actions, auto-reset, ``lax.scan`` of
``vmap(step)``, compile timed apart, best of repeats), on one id per family at one batch size
(4096 envs by default): Empty, DoorKey, FourRooms, KeyCorridor, LavaGap, SimpleCrossing,
DistShift, GoToDoor and Dynamic-Obstacles where both libraries have the id. NAVIX runs each
level with MiniGrid's ``max_steps``. Its observation is the full symbolic grid (no egocentric
crop, no occlusion), less work per step than jaxgrid's MiniGrid view; the ratio is quoted as
measured.
jaxgrid runs twice: with ``AutoReset`` (a fresh episode computed for every env on every step
and selected, as in ``env_throughput``) and with ``BatchedAutoReset`` (fresh episodes only
where one ended, as its learner steps it); NAVIX with its built-in auto-reset.

NAVIX needs an older JAX than jaxgrid's default environment; run this module from an
environment where both import (``pip install navix`` pins its JAX)::

    python -m benchmarks.family_throughput                     # ~10 min on 2 cores
    python -m benchmarks.family_throughput --num-envs 256 --ids MiniGrid-FourRooms-v0
    python -m benchmarks.family_throughput --json runs/family_throughput.json
"""

from __future__ import annotations

import argparse
import sys

from benchmarks import env_throughput as ET
from benchmarks.cli import integer, require
from checker.cli import run_main
from jaxgrid.io import write_json

#: One id per family that jaxgrid and NAVIX both ship.
FAMILY_IDS = (
    "MiniGrid-Empty-8x8-v0",
    "MiniGrid-DoorKey-8x8-v0",
    "MiniGrid-FourRooms-v0",
    "MiniGrid-KeyCorridorS3R3-v0",
    "MiniGrid-LavaGapS7-v0",
    "MiniGrid-SimpleCrossingS9N2-v0",
    "MiniGrid-DistShift1-v0",
    "MiniGrid-GoToDoor-8x8-v0",
    "MiniGrid-Dynamic-Obstacles-8x8-v0",
)


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(prog="python -m benchmarks.family_throughput", description=__doc__,
                                formatter_class=argparse.RawTextHelpFormatter)  # fmt: skip
    p.add_argument("--ids", nargs="+", default=list(FAMILY_IDS), help="MiniGrid ids to measure")
    p.add_argument("--num-envs", type=integer, default=4096)
    p.add_argument("--steps", type=integer, help="scan length (default: the harness's budget)")
    p.add_argument("--repeats", type=integer, default=3)
    p.add_argument("--json", help="also write the results to this JSON file")
    args = p.parse_args(argv)
    for name in ("num_envs", "repeats", "steps"):
        value = getattr(args, name)
        if value is not None and value < 1:
            p.error(f"--{name.replace('_', '-')} must be >= 1, got {value}")
    import jaxgrid

    unknown = [i for i in args.ids if i not in jaxgrid.registered_ids()]
    if unknown:
        p.error(f"--ids: {unknown[0]!r} is not a jaxgrid id")
    # NAVIX is the other side of every row: without it there is nothing to compare.
    require("navix", "every row (jaxgrid against NAVIX)")
    steps = args.steps or ET.default_steps(args.num_envs)
    rows, skipped = [], {}
    for env_id in args.ids:
        try:
            res = {
                lib: ET.measure(lib, args.num_envs, steps, args.repeats, env_id=env_id)
                for lib in ("jaxgrid", "jaxgrid-masked", "navix")
            }
        except ValueError as exc:  # an id one of them lacks
            skipped[env_id] = str(exc)
            print(f"{env_id}: skipped ({exc})", file=sys.stderr)
            continue
        navix = res["navix"]["steps_per_s"]
        row = {"env_id": env_id, "num_envs": args.num_envs}
        for lib, r in res.items():
            key = lib.replace("-", "_")
            row[f"{key}_steps_per_s"] = r["steps_per_s"]
            row[f"{key}_compile_s"] = r["compile_s"]
        row["ratio"] = row["jaxgrid_steps_per_s"] / navix
        row["ratio_masked"] = row["jaxgrid_masked_steps_per_s"] / navix
        rows.append(row)
        print(
            f"{env_id:<32} jaxgrid {ET._fmt_rate(row['jaxgrid_steps_per_s']):>7}/s "
            f"(masked {ET._fmt_rate(row['jaxgrid_masked_steps_per_s']):>7}/s) "
            f"navix {ET._fmt_rate(navix):>7}/s  x{row['ratio']:.2f} (masked "
            f"x{row['ratio_masked']:.2f})  compile {row['jaxgrid_compile_s']:.1f} s vs "
            f"{row['navix_compile_s']:.1f} s",
            flush=True,
        )
    out = {
        "rows": rows,
        "skipped": skipped,
        "machine": ET.machine_info(),
        "versions": ET.library_versions(),
    }
    if args.json:
        write_json(args.json, out)
    return out


if __name__ == "__main__":
    run_main(main, "python -m benchmarks.family_throughput")
