"""``agents.runner.run(..., multi_host=True)`` across processes joined by ``jax.distributed``.

Two processes with 2 host devices each (4 in all, CPU collectives over gloo) train a tiny
``shaped`` run with its env batch split over the 4 devices, checkpointing, stopping after its
first update and resuming; one process with 4 host devices trains the same run straight
through. The records of every update, the final evaluation, the final parameters and the
whole final runner state (optimiser, keys, envs) must be equal bit for bit: both sides run
the same partitioned program, whose only cross-device traffic is all-gathers and integer
all-reduces (XLA gathers the rollout for the minibatch shuffle and runs the update
replicated), all of them exact, so only the transport (gloo or in-process) differs. A
tolerance would hide a wrong shard order.

Slow: three fresh processes compile the sharded programs (about 25 s of CPU each); on 2
loaded cores the test takes minutes, not the default suite's seconds.
"""

from __future__ import annotations

import dataclasses
import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from helpers.agents_cases import TINY
from helpers.host_devices import ROOT, device_env

WORKER = ROOT / "tests" / "helpers" / "distributed_worker.py"
# One update per chunk, so that every record is one update's metrics; 3 updates.
CONFIG = dataclasses.replace(
    TINY, reward_mode="shaped", eval_every=1, total_timesteps=3 * TINY.batch_size
)
SEEDS = (0, 1)
FINAL_EPISODES = 4
TIMEOUT_S = 420  # for all three processes together


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _start(name: str, out: Path, devices: int, *args: str) -> tuple[subprocess.Popen, Path]:
    out.mkdir(parents=True, exist_ok=True)
    log = out.parent / f"{name}.log"
    config = json.dumps(dataclasses.asdict(CONFIG))
    seeds = ",".join(map(str, SEEDS))
    cmd = [sys.executable, str(WORKER), config, str(out), "--seeds", seeds, *args]
    with log.open("w") as f:  # a file, not a pipe: a chatty child never blocks on it
        proc = subprocess.Popen(cmd, cwd=ROOT, env=device_env(devices), stdout=f, stderr=f)
    return proc, log


def _wait(procs: dict[str, tuple[subprocess.Popen, Path]]) -> None:
    """Wait for every process within TIMEOUT_S; on a failure or timeout kill the others and
    fail with every process's log tail."""
    deadline = time.monotonic() + TIMEOUT_S
    failed = None
    while failed is None and any(p.poll() is None for p, _ in procs.values()):
        if time.monotonic() > deadline:
            failed = f"timed out after {TIMEOUT_S} s"
        elif any(p.poll() not in (None, 0) for p, _ in procs.values()):
            failed = "a process failed"
        else:
            time.sleep(0.2)
    for p, _ in procs.values():
        if p.poll() is None:
            p.kill()
        p.wait()
    if failed is None and all(p.returncode == 0 for p, _ in procs.values()):
        return
    logs = "\n".join(
        f"----- {name} (exit {p.returncode}) -----\n{log.read_text()[-3000:]}"
        for name, (p, log) in procs.items()
    )
    pytest.fail(f"{failed or 'a process failed'}\n{logs}")


def _arrays(path: Path) -> list[np.ndarray]:
    with np.load(path) as f:
        return [f[f"arr_{i}"] for i in range(len(f.files))]


@pytest.mark.slow
def test_two_processes_match_one_process(tmp_path):
    multi, single = tmp_path / "multi", tmp_path / "single"
    coordinator = f"127.0.0.1:{_free_port()}"
    final = ["--final-episodes", str(FINAL_EPISODES)]
    joined = ["--coordinator", coordinator, "--processes", "2", "--interrupt-after", "1", *final]
    procs = {
        f"process {i}": _start(f"process{i}", multi, 2, *joined, "--process-id", str(i))
        for i in range(2)
    }
    procs["single"] = _start("single", single, 4, "--no-out-dir", *final)
    _wait(procs)

    results = [json.loads((multi / f"result-{i}.json").read_text()) for i in range(2)]
    reference = json.loads((single / "result-0.json").read_text())
    assert reference["process_count"] == 1 and reference["local_devices"] == 4
    for i, r in enumerate(results):
        assert (r["process_index"], r["process_count"]) == (i, 2)
        assert (r["devices"], r["local_devices"]) == (4, 2)
        # The env batch (seed axis, then envs) really is split over all 4 devices.
        assert r["env_devices"] == 4
        assert r["env_shard_shape"][1] * 4 == r["env_shape"][1] == CONFIG.num_envs
        # One record per seed and update, the same in both processes and in one process.
        assert len(r["records"]) == len(SEEDS) * CONFIG.num_updates
        assert r["records"] == reference["records"]
        assert r["final"] == reference["final"]
        assert len(r["final"]["success_rate"]) == len(SEEDS)
    for name in ("params", "runner"):
        expected = _arrays(single / f"{name}-0.npz")
        for i in range(2):
            got = _arrays(multi / f"{name}-{i}.npz")
            assert len(got) == len(expected)
            for a, b in zip(got, expected, strict=True):
                np.testing.assert_array_equal(a, b, err_msg=f"{name}, process {i}")

    # Process 0 alone wrote the log (each record once) and the checkpoint digests.
    lines = (multi / "run" / "metrics.jsonl").read_text().splitlines()
    assert [json.loads(line) for line in lines] == reference["records"]
    digests = json.loads((multi / "run" / "checkpoints.json").read_text())
    kept = sorted(p.name for p in (multi / "run" / "checkpoints").iterdir())
    assert sorted(digests) == kept == [str(CONFIG.num_chunks - 1), str(CONFIG.num_chunks)]
