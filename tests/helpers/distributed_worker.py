"""One process of a training run through :func:`agents.runner.run`, for the multi-process
tests: alone (every device of the process) or as process ``--process-id`` of ``--processes``
joined through ``jax.distributed`` (CPU collectives over gloo, ``multi_host=True``).

``python distributed_worker.py CONFIG_JSON OUT_DIR [--coordinator HOST:PORT --processes N
--process-id I] [--interrupt-after K] [--no-out-dir] [--final-episodes E]``. The host devices
come from ``XLA_FLAGS`` (``--xla_force_host_platform_device_count``). The run's files go to
``OUT_DIR/run`` (none with ``--no-out-dir``); ``--interrupt-after K`` stops the run after K
chunks and resumes it from its checkpoint in a second call. Every process then writes
``OUT_DIR/result-<process>.json`` (records, final evaluation, devices, env sharding) and
``OUT_DIR/{params,runner}-<process>.npz`` (the final parameters and whole runner state,
gathered from all processes), for a test to compare with a single-process run.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("config", help="PPOConfig fields as JSON")
    parser.add_argument("out", type=Path)
    parser.add_argument("--coordinator", default=None)
    parser.add_argument("--processes", type=int, default=1)
    parser.add_argument("--process-id", type=int, default=0)
    parser.add_argument("--seeds", default="0,1")
    parser.add_argument("--interrupt-after", type=int, default=None, help="then resume")
    parser.add_argument("--no-out-dir", action="store_true", help="write no run files")
    parser.add_argument("--final-episodes", type=int, default=0)
    args = parser.parse_args(argv)

    import jax

    multi_host = args.processes > 1
    if multi_host:
        # gloo is the CPU default of recent JAX; named so that an older default fails loudly.
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(
            coordinator_address=args.coordinator,
            num_processes=args.processes,
            process_id=args.process_id,
            initialization_timeout=60,
        )

    import numpy as np
    from jax.experimental import multihost_utils

    from agents.config import PPOConfig
    from agents.runner import run

    config = PPOConfig(**json.loads(args.config))  # it normalises JSON's lists itself
    seeds = tuple(int(s) for s in args.seeds.split(","))
    out_dir = None if args.no_out_dir else args.out / "run"
    kwargs = dict(seeds=seeds, progress=False, multi_host=multi_host, out_dir=out_dir)
    if args.interrupt_after is not None:
        first = run(config, max_chunks=args.interrupt_after, **kwargs)
        assert not first["complete"], "the interrupted call ran the whole run"
    result = run(config, final_episodes=args.final_episodes, **kwargs)

    pid = jax.process_index()
    # Parameters are replicated: every process reads them as they are. The runner state
    # (optimiser, keys, envs) holds env leaves split over the processes: gathered.
    params = [np.asarray(x) for x in jax.tree.leaves(result["params"])]
    np.savez(args.out / f"params-{pid}.npz", *params)
    gather = functools.partial(multihost_utils.process_allgather, tiled=True)
    runner = [np.asarray(gather(x)) for x in jax.tree.leaves(result["runner"])]
    np.savez(args.out / f"runner-{pid}.npz", *runner)
    env_leaf = jax.tree.leaves(result["runner"].env)[0]
    summary = {
        "process_index": pid,
        "process_count": jax.process_count(),
        "devices": jax.device_count(),
        "local_devices": jax.local_device_count(),
        "env_devices": len(env_leaf.sharding.device_set),
        "env_shape": list(env_leaf.shape),
        "env_shard_shape": list(env_leaf.sharding.shard_shape(env_leaf.shape)),
        "records": result["records"],
        "final": jax.tree.map(lambda x: np.asarray(x).tolist(), result.get("final")),
        "config": dataclasses.asdict(config),
    }
    (args.out / f"result-{pid}.json").write_text(json.dumps(summary, default=repr))
    if multi_host:
        jax.distributed.shutdown()


if __name__ == "__main__":
    sys.exit(main())
