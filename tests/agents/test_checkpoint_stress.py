"""Checkpoints (``agents.checkpoint``) saved from several threads at once, as the experiments
save two reward modes' runs, never collide: hundreds of saves under CPU load, no error,
and each directory's newest checkpoint restores, files and records verified, to what was
saved. A save that fails is a ``CheckpointError`` naming the checkpoint that is kept.

The saves go through the functions ``agents.runner.run`` calls (one save per chunk), not
through ``run`` itself: a chunk of training would make hundreds of saves take minutes.
"""

from __future__ import annotations

import tempfile
import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from agents import checkpoint
from agents.checkpoint import CheckpointError
from jaxgrid import io

THREADS = 3
SAVES = 70  # per thread: 210 in all
JOIN_S = 180  # a save that waits for a signal that never comes would otherwise hang here
# The collision is between threads of one process, not in the file system: tmpfs, where
# there is one, spares the test the disk's deletes and fsyncs (half of a save's time).
FAST_DIR = Path("/dev/shm") if Path("/dev/shm").is_dir() else None


def state(agent: int, step: int) -> dict:
    """A small runner-like state (float parameters, a key, a counter) unique to each save."""
    return {
        "params": {"w": jnp.full((64,), agent * 1000.0 + step, jnp.float32),
                   "b": jnp.arange(8, dtype=jnp.float32) * step},
        "key": jax.random.PRNGKey(step),
        "update": jnp.asarray(step, jnp.int32),
    }  # fmt: skip


def record(agent: int, step: int) -> dict:
    """The log record of chunk ``step - 1``, as ``run`` appends one before each save."""
    return {"seed": agent, "chunk": step - 1, "loss": agent + step / 7}


def save_every_chunk(out, agent: int, saves: int, errors: list) -> None:
    """Save ``saves`` checkpoints into ``out`` as ``run`` does, collecting any error."""
    manager = checkpoint.make_manager(out / "checkpoints")
    records = []
    try:
        for step in range(1, saves + 1):
            records.append(record(agent, step))
            io.append_jsonl(out / "metrics.jsonl", records[-1:])
            try:
                checkpoint.save(manager, step, state(agent, step), out, records)
            except Exception as e:  # every error counts, whatever its type
                errors.append(f"{out.name}, step {step}: {type(e).__name__}: {e}")
    finally:
        manager.close()


def load(stop: threading.Event) -> None:
    """CPU load beside the saves: matrix products, which release the GIL, as training does."""
    a = np.random.default_rng(0).standard_normal((256, 256))
    while not stop.is_set():
        a = np.tanh(a @ a)


@pytest.fixture
def fast_path(tmp_path):
    """An empty directory in memory where possible (else ``tmp_path``), removed afterwards."""
    if FAST_DIR is None:
        yield tmp_path
        return
    with tempfile.TemporaryDirectory(dir=FAST_DIR, prefix="checkpoint-stress-") as path:
        yield Path(path)


@pytest.mark.slow
def test_saves_from_several_threads_never_collide(fast_path):
    dirs = [fast_path / "modes" / f"mode{i}" for i in range(THREADS)]
    errors: list[str] = []
    stop = threading.Event()
    burner = threading.Thread(target=load, args=(stop,), daemon=True)
    savers = [threading.Thread(target=save_every_chunk, args=(d, i, SAVES, errors), daemon=True)
              for i, d in enumerate(dirs)]  # fmt: skip
    start = time.perf_counter()
    burner.start()
    for t in savers:
        t.start()
    for t in savers:
        t.join(timeout=max(1.0, JOIN_S - (time.perf_counter() - start)))
    stop.set()
    assert not [t for t in savers if t.is_alive()], f"saves hung; errors so far: {errors[:3]}"
    assert errors == [], f"{len(errors)} of {THREADS * SAVES} saves failed: {errors[:3]}"

    ident = lambda r: (r["seed"],)  # noqa: E731 (the agent a record belongs to)
    for i, out in enumerate(dirs):
        manager = checkpoint.make_manager(out / "checkpoints")
        try:
            assert manager.all_steps() == [SAVES - 1, SAVES]
            step, records = checkpoint.resume_point(manager, out, [(i,)], ident)
            assert step == SAVES
            assert records == [record(i, s) for s in range(1, SAVES + 1)]
            abstract = jax.eval_shape(lambda i=i: state(i, SAVES))
            restored = checkpoint.restore(manager, SAVES, abstract, None)
        finally:
            manager.close()
        expected = state(i, SAVES)
        assert jax.tree.structure(restored) == jax.tree.structure(expected)
        for a, b in zip(jax.tree.leaves(restored), jax.tree.leaves(expected), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert not list(fast_path.rglob("*.orbax-checkpoint-tmp*"))  # every save was finalised


def test_a_failed_save_is_a_checkpoint_error_naming_the_kept_checkpoint(tmp_path):
    checkpoints = tmp_path / "checkpoints"
    unsavable = {"x": object()}  # orbax raises on a leaf it cannot write
    manager = checkpoint.make_manager(checkpoints)
    try:
        with pytest.raises(CheckpointError, match="no checkpoint was written yet"):
            checkpoint.save(manager, 1, unsavable, tmp_path, [record(0, 1)])
        checkpoint.save(manager, 1, state(0, 1), tmp_path, [record(0, 1)])

        # orbax raises: the error names the step, its directory and the kept checkpoint.
        with pytest.raises(CheckpointError) as e:
            checkpoint.save(manager, 2, unsavable, tmp_path, [record(0, 2)])
        assert isinstance(e.value, OSError) and isinstance(e.value.__cause__, ValueError)
        message = str(e.value)
        assert f"checkpoint 2 could not be saved in {checkpoints}" in message
        assert f"the last good checkpoint (chunk 1) is kept in {checkpoints}" in message
        assert manager.all_steps() == [1]
        assert checkpoint.verified_step(manager, tmp_path, delete=False) == 1

        # The step saves once the problem is gone; orbax declining a save (save() returns
        # False: a step older than the newest) is an error too.
        checkpoint.save(manager, 2, state(0, 2), tmp_path, [record(0, 2)])
        with pytest.raises(CheckpointError, match=r"refused .* the last good checkpoint "
                                                  r"\(chunk 2\)"):  # fmt: skip
            checkpoint.save(manager, 1, state(0, 1), tmp_path, [record(0, 1)])
        assert manager.all_steps() == [1, 2]
        assert checkpoint.verified_step(manager, tmp_path, delete=False) == 2
    finally:
        manager.close()
