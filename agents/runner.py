"""Drive training from the host: seeds, devices, progress, JSONL logs, checkpoints, resume.

:func:`run` executes the same pure pieces as :func:`agents.train.make_train`, one chunk of
``eval_every`` updates at a time, ``jit(vmap(...))`` over seeds, so that metrics reach the
host as they happen (a tqdm bar and one JSONL line per seed and chunk), checkpoints can be
written between chunks, and a killed run resumes where its last checkpoint left it with the
same final parameters as an uninterrupted run (the whole runner state, RNG and environments
included, is saved).

**Devices.** With more than one local device, the environment batch (every leaf of
:class:`agents.rollout.EnvCarry`) is sharded along its env axis over a 1-D ``jax.sharding.Mesh``
named ``"envs"``; parameters, optimiser state and keys are replicated. XLA partitions the
rollout and inserts the collectives of the minibatch shuffle. For several hosts, call
``jax.distributed.initialize()`` in every process before :func:`run`: the mesh is then
built over ``jax.devices()`` (all hosts) instead of the local ones (``multi_host=True``).
"""

from __future__ import annotations

import dataclasses
import json
import os
import time
from collections import OrderedDict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from agents.config import PPOConfig
from agents.evaluation import summarise
from agents.train import Learner, RunnerState, make_learner
from jaxgrid import io


class NonFiniteError(FloatingPointError):
    """Training produced a non-finite loss or parameters."""


def _mesh(num_envs: int, multi_host: bool = False) -> Mesh | None:
    devices = jax.devices() if multi_host else jax.local_devices()
    if len(devices) == 1:
        return None
    if num_envs % len(devices):
        raise ValueError(
            f"PPOConfig.num_envs ({num_envs}) must be divisible by the number of devices "
            f"({len(devices)}) to shard the environment batch"
        )
    return Mesh(np.asarray(devices), ("envs",))


def _shardings(runner: RunnerState, mesh: Mesh):
    """Env leaves split on axis 1 (axis 0 is the seed axis); everything else replicated."""
    replicated = NamedSharding(mesh, PartitionSpec())
    split = NamedSharding(mesh, PartitionSpec(None, "envs"))
    return runner.replace(
        params=jax.tree.map(lambda _: replicated, runner.params),
        opt_state=jax.tree.map(lambda _: replicated, runner.opt_state),
        lagrange=replicated,
        key=replicated,
        update=replicated,
        env=jax.tree.map(lambda _: split, runner.env),
    )


def _finite(tree) -> jax.Array:
    leaves = [
        jnp.all(jnp.isfinite(x))
        for x in jax.tree.leaves(tree)
        if jnp.issubdtype(x.dtype, jnp.floating)
    ]
    return jnp.all(jnp.stack(leaves))


def _host(x) -> Any:
    return jax.tree.map(lambda a: np.asarray(a), x)


def chunk_records(
    config: PPOConfig, chunk: int, seeds: Sequence[int], metrics, totals: np.ndarray
) -> list[dict]:
    """One JSON-serialisable record per seed for chunk ``chunk`` (0-based)."""
    train, evaluation = metrics["train"], metrics["eval"]
    step = (chunk + 1) * config.eval_every * config.batch_size
    records = []
    for i, seed in enumerate(seeds):
        t = {k: v[i] for k, v in train.items()}
        episodes = int(t["episodes"].sum())
        records.append(
            {
                "seed": int(seed),
                "chunk": chunk,
                "update": (chunk + 1) * config.eval_every,
                "step": step,
                **{f"eval/{k}": float(v[i]) for k, v in evaluation.items()},
                "train/episodes": episodes,
                "train/success_rate": float(t["successes"].sum() / max(episodes, 1)),
                "train/episode_return": float(
                    (t["episode_return"] * t["episodes"]).sum() / max(episodes, 1)
                ),
                "train/violations": int(t["violations"].sum()),
                "train/cum_violations": int(totals[i]),
                "train/alarms": int(t["alarms"].sum()),
                "train/cost_rate": float(t["cost_rate"].mean()),
                "train/episode_cost": float(t["episode_cost"].mean()),
                "train/novelty_rate": float(t["novelty_rate"].mean()),
                "train/lagrange": float(t["lagrange"][-1]),
                "loss": float(t["loss"].mean()),
                "entropy": float(t["entropy"].mean()),
                "approx_kl": float(t["approx_kl"].mean()),
            }
        )
    return records


def run(
    config: PPOConfig,
    checker=None,
    *,
    seeds: Sequence[int] = (0,),
    out_dir: str | os.PathLike | None = None,
    checkpoint_every: int = 1,
    resume: bool = True,
    progress: bool = True,
    multi_host: bool = False,
    final_episodes: int = 0,
    desc: str | None = None,
    max_chunks: int | None = None,
) -> dict:
    """Train ``len(seeds)`` agents at once (vmapped); return their histories and parameters.

    Args:
        config: the run (``config.seed`` is ignored: ``seeds`` are used).
        checker: a :class:`checker.TrainedChecker`, required by the checker modes.
        out_dir: where ``metrics.jsonl``, ``checkpoints/`` and ``run.json`` (the config and
            seeds) go; ``None`` keeps nothing.
        checkpoint_every: save every this many chunks of ``config.eval_every`` updates
            (0: never). Saved only after the chunk's loss and parameters are checked finite.
        resume: continue from the newest checkpoint in ``out_dir`` if there is one (a
            ``ValueError`` if it was made with another config or other seeds); ``False``
            deletes its checkpoints and starts over.
        final_episodes: if > 0, a final evaluation over this many fixed-seed episodes.
        max_chunks: stop after this many chunks in this call (simulates an interruption;
            the checkpoint lets a later call resume).

    Returns a dict with ``steps`` (num_chunks,), ``eval`` {metric: (seeds, chunks)},
    ``train_violations`` (seeds,), ``records`` (the JSONL records), ``params`` (stacked
    over seeds), ``final`` {metric: (seeds,)} when ``final_episodes`` and ``wall_s``.

    Raises:
        ValueError: bad configuration (before any compilation), or a resume of ``out_dir``
            with another configuration or other seeds.
        NonFiniteError: a chunk produced a non-finite loss or parameters; the message names
            the update, and the last good checkpoint is left untouched.
    """
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ValueError("seeds must name at least one seed")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"seeds must be distinct, got {seeds}")
    if checkpoint_every < 0:
        raise ValueError(f"checkpoint_every must be >= 0, got {checkpoint_every}")
    if max_chunks is not None and max_chunks < 0:
        raise ValueError(f"max_chunks must be >= 0 or None, got {max_chunks}")
    programs = _programs(config, checker, multi_host)
    learner: Learner = programs.learner
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()

    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    abstract = jax.eval_shape(jax.vmap(learner.init), keys)
    shardings = programs.shardings
    init, chunk = programs.init, programs.chunk

    manager = bar = None
    done_chunks, records, totals = 0, [], np.zeros(len(seeds), np.int64)
    try:
        if out is not None and checkpoint_every:
            manager = _checkpoint_manager(out / "checkpoints")
        runner = None
        if manager is not None and manager.latest_step() is not None:
            if resume:
                _check_run_info(out, config, seeds)
                done_chunks = int(manager.latest_step())
                runner = _restore(manager, done_chunks, abstract, shardings)
                records = _read_records(out / "metrics.jsonl", done_chunks)
                for r in records:
                    i = seeds.index(r["seed"])
                    totals[i] = max(totals[i], r["train/cum_violations"])
            else:
                # A fresh run: orbax would silently refuse to overwrite an existing step
                # (save() returns False), leaving the old run's state for a later resume.
                for step in manager.all_steps():
                    manager.delete(step)
        if runner is None:
            runner = init(keys)
        if out is not None:
            _write_run_info(out, config, seeds)
            io.write_jsonl(out / "metrics.jsonl", records)

        bar = _progress(config.num_chunks, done_chunks, progress, desc or config.reward_mode)
        stop = (
            config.num_chunks
            if max_chunks is None
            else min(config.num_chunks, done_chunks + max_chunks)
        )
        for c in range(done_chunks, stop):
            new_runner, metrics, finite = chunk(runner)
            metrics, finite = _host(metrics), np.asarray(finite)
            if not finite.all():
                bad = [seeds[i] for i in np.flatnonzero(~finite)]
                kept = f"is kept in {out / 'checkpoints'}" if manager else "was not requested"
                raise NonFiniteError(
                    f"non-finite loss or parameters within updates {c * config.eval_every + 1}-"
                    f"{(c + 1) * config.eval_every} (seeds {bad}); the last good checkpoint "
                    f"{kept}"
                )
            runner = new_runner
            totals += metrics["train"]["violations"].sum(axis=1).astype(np.int64)
            new = chunk_records(config, c, seeds, metrics, totals)
            records.extend(new)
            if out is not None:
                io.append_jsonl(out / "metrics.jsonl", new)
            last = c + 1 == config.num_chunks
            if manager is not None and ((c + 1) % checkpoint_every == 0 or last):
                if not manager.save(c + 1, args=_save_args(runner)):
                    raise RuntimeError(f"orbax did not save checkpoint {c + 1} in {out}")
                manager.wait_until_finished()
            if bar is not None:
                bar.update(1)
                bar.set_postfix(
                    viol=f"{np.mean([r['eval/violation_rate'] for r in new]):.2f}",
                    succ=f"{np.mean([r['eval/success_rate'] for r in new]):.2f}",
                )
    finally:
        if bar is not None:
            bar.close()
        if manager is not None:
            manager.close()

    result = _collect(config, seeds, records)
    result["params"] = runner.params
    result["runner"] = runner
    result["complete"] = stop == config.num_chunks
    if final_episodes:
        result["final"] = _host(programs.final(final_episodes)(runner.params))
        result["final_episodes"] = final_episodes
    result["wall_s"] = time.perf_counter() - start
    return result


class _Programs:
    """The jitted pieces of :func:`run` for one (config, checker, devices) combination.

    Cached per process (a few entries), so that calling :func:`run` again with the same
    configuration, e.g. to resume, to add seeds or from a sweep, does not compile again.
    """

    def __init__(self, config: PPOConfig, checker, multi_host: bool):
        learner = make_learner(config, checker)
        mesh = _mesh(config.num_envs, multi_host)
        abstract = jax.eval_shape(jax.vmap(learner.init), jax.random.PRNGKey(0)[None])
        # Explicit shardings on one device too: the arrays orbax restores are committed to
        # a device, the output of a jit without out_shardings is not, and jit would compile
        # the chunk again for the resumed (committed) runner state.
        devices = jax.devices() if multi_host else jax.local_devices()
        one = Mesh(np.asarray(devices[:1]), ("envs",))
        shardings = _shardings(abstract, mesh if mesh is not None else one)

        def chunk_fn(runner):
            runner, metrics = jax.vmap(learner.chunk)(runner)
            finite = jax.vmap(lambda r, m: _finite((r.params, m["train"]["loss"])))(runner, metrics)
            return runner, metrics, finite

        self.checker = checker  # keeps id(checker) of the cache key alive
        self.learner, self.mesh, self.shardings = learner, mesh, shardings
        self.init = jax.jit(jax.vmap(learner.init), out_shardings=shardings)
        self.chunk = jax.jit(
            chunk_fn, in_shardings=(shardings,), out_shardings=(shardings, None, None)
        )
        self._final: dict[int, Any] = {}

    def final(self, num_episodes: int):
        if num_episodes not in self._final:
            config, learner = self.learner.config, self.learner
            key = jax.random.PRNGKey(config.eval_seed + 1)
            self._final[num_episodes] = jax.jit(
                jax.vmap(lambda p: summarise(learner.evaluate(p, key, num_episodes)))
            )
        return self._final[num_episodes]


_PROGRAMS: OrderedDict = OrderedDict()
_MAX_PROGRAMS = 4


def _programs(config: PPOConfig, checker, multi_host: bool) -> _Programs:
    devices = jax.devices() if multi_host else jax.local_devices()
    key = (config, None if checker is None else id(checker), tuple(d.id for d in devices))
    if key in _PROGRAMS:
        _PROGRAMS.move_to_end(key)  # config and checker were validated when it was built
        return _PROGRAMS[key]
    programs = _Programs(config, checker, multi_host)
    _PROGRAMS[key] = programs
    while len(_PROGRAMS) > _MAX_PROGRAMS:
        _PROGRAMS.popitem(last=False)
    return programs


def _run_info(config: PPOConfig, seeds: list[int]) -> dict:
    fields = {k: v for k, v in dataclasses.asdict(config).items() if k != "seed"}
    return json.loads(json.dumps({"config": fields, "seeds": seeds}, default=repr))


def _write_run_info(out: Path, config: PPOConfig, seeds: list[int]) -> None:
    io.write_json(out / "run.json", _run_info(config, seeds))


def _check_run_info(out: Path, config: PPOConfig, seeds: list[int]) -> None:
    """Refuse to resume a run made with another configuration or other seeds."""
    path = out / "run.json"
    if not path.exists():
        return
    saved, now = io.read_json(path), _run_info(config, seeds)
    if saved["seeds"] != now["seeds"]:
        raise ValueError(
            f"cannot resume {out}: it was run with seeds {saved['seeds']}, not {seeds} "
            "(pass resume=False to start over, or another out_dir)"
        )
    diff = sorted(
        k for k in set(saved["config"]) | set(now["config"])
        if saved["config"].get(k) != now["config"].get(k)
    )  # fmt: skip
    if diff:
        raise ValueError(
            f"cannot resume {out}: PPOConfig differs in {diff} (saved "
            f"{ {k: saved['config'].get(k) for k in diff} }); pass resume=False to start "
            "over, or another out_dir"
        )


# ----------------------------------------------------------------------------------------
def _collect(config: PPOConfig, seeds: list[int], records: list[dict]) -> dict:
    chunks = sorted({r["chunk"] for r in records})
    by = {(r["seed"], r["chunk"]): r for r in records}
    keys = ("eval/violation_rate", "eval/mean_reward", "eval/success_rate")
    evaluation = {
        k.split("/")[1]: np.array([[by[s, c][k] for c in chunks] for s in seeds]) for k in keys
    }
    last = chunks[-1] if chunks else None
    return {
        "steps": np.array([(c + 1) * config.eval_every * config.batch_size for c in chunks]),
        "eval": evaluation,
        "train_violations": np.array(
            [by[s, last]["train/cum_violations"] if last is not None else 0 for s in seeds]
        ),
        "train_alarms": np.array([sum(by[s, c]["train/alarms"] for c in chunks) for s in seeds]),
        "records": records,
        "seeds": seeds,
    }


def _progress(total, initial, enabled, desc):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="chunk", dynamic_ncols=True)


def _checkpoint_manager(path: Path):
    import orbax.checkpoint as ocp

    options = ocp.CheckpointManagerOptions(max_to_keep=2, create=True)
    return ocp.CheckpointManager(path.absolute(), options=options)


def _save_args(runner):
    import orbax.checkpoint as ocp

    return ocp.args.StandardSave(runner)


def _restore(manager, step, abstract, shardings):
    import orbax.checkpoint as ocp

    if shardings is not None:
        target = jax.tree.map(
            lambda a, s: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=s), abstract, shardings
        )
    else:
        target = abstract
    return manager.restore(step, args=ocp.args.StandardRestore(target))


def _read_records(path: Path, chunks: int) -> list[dict]:
    if not path.exists():
        return []
    return [r for r in io.read_jsonl(path) if r["chunk"] < chunks]
