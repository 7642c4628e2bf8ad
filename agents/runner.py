"""Drive training from the host: seeds, sweeps, progress, JSONL logs, checkpoints, resume.

:func:`run` executes the same pure pieces as :func:`agents.train.make_train`, one chunk of
``eval_every`` updates at a time, ``jit(vmap(...))`` over seeds, so that metrics reach the
host as they happen (a tqdm bar and one JSONL line per seed and chunk), checkpoints can be
written between chunks, and a killed run resumes where its last checkpoint left it with the
same final parameters as an uninterrupted run (the whole runner state, RNG and environments
included, is saved).

The loop's pieces live beside it: :mod:`agents.devices` (the env batch split over several
devices or hosts, ``multi_host``), :mod:`agents.programs` (the compiled programs, kept
between calls; :func:`agents.programs.precompile`) and :mod:`agents.checkpoint` (saves,
digests, resume points and ``run.json``).
"""

from __future__ import annotations

import functools
import itertools
import os
import threading
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.experimental import multihost_utils

from agents import checkpoint, run_record
from agents.config import PPOConfig, check_sweep
from agents.devices import to_host
from agents.programs import programs_for
from agents.train import Learner, make_learner
from jaxgrid import io
from jaxgrid.constrained import ConstrainedEnvironment

__all__ = ["EARLY_FRACTION", "Cancelled", "NonFiniteError", "chunk_records", "early_updates",
           "load_agents", "run"]  # fmt: skip


class NonFiniteError(FloatingPointError):
    """Training produced a non-finite loss or parameters."""


class Cancelled(Exception):
    """:func:`run` stopped between two chunks because its ``cancel`` event was set; the
    checkpoints written so far are kept, so the run resumes where it stopped."""


EARLY_FRACTION = 0.2  # "early in training": training violations are also split there


def early_updates(config: PPOConfig) -> int:
    """The updates of the first :data:`EARLY_FRACTION` of training (rounded to the nearest)."""
    return int(round(EARLY_FRACTION * config.num_updates))


def chunk_records(
    config: PPOConfig,
    chunk: int,
    seeds: Sequence[int],
    metrics,
    totals: np.ndarray,
    swept: dict[str, Sequence[float]] | None = None,
    cost_totals: np.ndarray | None = None,
) -> list[dict]:
    """One JSON-serialisable record per agent for chunk ``chunk`` (0-based); ``seeds`` and
    the ``swept`` hyperparameters' values are per agent (the record holds both).

    ``totals`` are the agents' training violations and ``cost_totals`` (float) their env
    costs, both summed from update 0 to this chunk's last; an unknown one (NaN, or None for
    all: a run resumed from records older than the cost metrics) is logged as null.
    ``train/cum_env_cost_rate`` is OmniSafe's cost rate: the env cost of every training step
    so far over the number of those steps."""
    train, evaluation = metrics["train"], metrics["eval"]
    step = (chunk + 1) * config.eval_every * config.batch_size
    # Updates in the first EARLY_FRACTION of training (its first env steps).
    early = chunk * config.eval_every + np.arange(config.eval_every) < early_updates(config)
    if cost_totals is None:
        cost_totals = np.full(len(seeds), np.nan)
    records = []
    for i, seed in enumerate(seeds):
        t = {k: v[i] for k, v in train.items()}
        episodes = int(t["episodes"].sum())
        cum_cost = None if np.isnan(cost_totals[i]) else float(cost_totals[i])
        records.append(
            {
                "seed": int(seed),
                **{name: float(values[i]) for name, values in (swept or {}).items()},
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
                "train/violations_early": int(t["violations"][early].sum()),
                "train/cum_violations": int(totals[i]),
                "train/env_cost": float(t["env_cost"].astype(np.float64).sum()),
                "train/cum_env_cost": cum_cost,
                "train/cum_env_cost_rate": None if cum_cost is None else cum_cost / step,
                "train/alarms": int(t["alarms"].sum()),
                "train/blocked": int(t["blocked"].sum()),
                "train/blocked_rate": float(t["blocked_rate"].mean()),
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
    sweep: Mapping[str, Sequence[float]] | None = None,
    cancel: threading.Event | None = None,
) -> dict:
    """Train ``len(seeds)`` agents at once (vmapped); return their histories and parameters.

    With ``sweep`` {name: values} (names of :data:`agents.config.SWEEPABLE`) every seed runs
    with every combination of the values, all in the same compiled program: agents are
    ordered by combination (the first name's values outermost), then by seed.

    Args:
        config: the run (``config.seed`` is ignored: ``seeds`` are used).
        checker: a :class:`checker.TrainedChecker`, required by the checker modes.
        out_dir: where ``metrics.jsonl``, ``checkpoints/`` and ``run.json`` (the config and
            seeds) go; ``None`` keeps nothing.
        checkpoint_every: save every this many chunks of ``config.eval_every`` updates
            (0: never). Saved only after the chunk's loss and parameters are checked finite.
        resume: continue from the newest checkpoint in ``out_dir`` whose files and logged
            records match their digests (:mod:`agents.checkpoint`; newer ones are deleted
            with a message and their chunks redone); a ``ValueError`` if it was made with
            another config or other seeds, a :class:`~agents.checkpoint.ResumeError` if it
            was made with another checker or no checkpoint matches; ``False`` deletes its
            checkpoints and starts over.
        multi_host: split the env batch over the devices of every process that joined
            ``jax.distributed`` (:mod:`agents.devices`); each process calls ``run`` alike.
        final_episodes: if > 0, a final evaluation over this many fixed-seed episodes.
        max_chunks: stop after this many chunks in this call (simulates an interruption;
            the checkpoint lets a later call resume).
        sweep: hyperparameter values swept in the same program (see above); a resume must
            name the same ones.
        cancel: checked before every chunk; once set, the run raises :class:`Cancelled`
            (a run in another thread stops at its next checkpoint).

    Returns a dict with ``steps`` (num_chunks,), ``eval`` {metric: (seeds, chunks)},
    (an axis ``seeds`` has one entry per agent), ``seeds`` (the seed of each agent) and,
    with a sweep, ``sweep`` {name: (agents,) values};
    ``train_violations`` (seeds,: from update 0) and ``train_violations_early`` (seeds,: in
    the first :data:`EARLY_FRACTION` of the updates), ``train_env_cost`` (seeds,: the env's
    cost summed from update 0) and ``train_cost_rate`` (seeds, chunks: OmniSafe's cost rate,
    that cost over the steps so far, after each chunk; both absent for a run resumed from
    records older than them), ``records`` (the JSONL records), ``params`` (stacked
    over seeds), ``final`` {metric: (seeds,)} when ``final_episodes`` (in the shield modes
    with ``final["unshielded"]``, the policy without its shield) and ``wall_s``.

    Raises:
        ValueError: bad configuration (before any compilation), or a resume of ``out_dir``
            with another configuration or other seeds.
        agents.checkpoint.ResumeError: ``out_dir`` holds a checkpoint that cannot be resumed
            (see ``resume``).
        Cancelled: ``cancel`` was set.
        agents.checkpoint.CheckpointError: a checkpoint could not be saved; the message names
            the last good one, which is kept.
        NonFiniteError: a chunk produced a non-finite loss or parameters; the message names
            the update and the last good checkpoint's directory, or says that none was
            written yet; that checkpoint is left untouched.
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
    sweep = check_sweep(sweep, config)
    swept, idents = _agents(sweep, seeds)
    ident = functools.partial(_ident, names=tuple(sweep))
    seeds = [agent[0] for agent in idents]  # the seed of each agent
    programs = programs_for(config, checker, multi_host, tuple(sweep))
    learner: Learner = programs.learner
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    # Under jax.distributed every process runs this function; process 0 alone writes the
    # logs and shows progress (orbax coordinates the checkpoint writes of all of them).
    primary = jax.process_index() == 0
    start = time.perf_counter()

    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    hparams = {n: jnp.asarray(v, jnp.float32) for n, v in swept.items()}
    abstract = jax.eval_shape(jax.vmap(learner.init), keys, hparams)
    shardings = programs.shardings
    init, chunk = programs.executable("init", len(seeds)), programs.executable("chunk", len(seeds))

    manager = bar = None
    done_chunks, records, totals = 0, [], np.zeros(len(seeds), np.int64)
    cost_totals = np.zeros(len(seeds), np.float64)
    try:
        if out is not None and checkpoint_every:
            manager = checkpoint.make_manager(out / "checkpoints")
        runner = None
        if manager is not None and manager.latest_step() is not None:
            if resume:
                run_record.check_run_info(out, config, seeds, checker, sweep)
                done_chunks, records = checkpoint.resume_point(manager, out, idents, ident)
                upgrade = functools.partial(_upgrade, learner.env)
                runner = checkpoint.restore(manager, done_chunks, abstract, shardings, upgrade)
                for r in records:
                    i = idents.index(ident(r))
                    totals[i] = max(totals[i], r["train/cum_violations"])
                    # Unknown (NaN) for good where a record predates the cost metrics.
                    cost = r.get("train/cum_env_cost")
                    cost_totals[i] = np.nan if cost is None else max(cost_totals[i], cost)
            else:
                # A fresh run: orbax would silently refuse to overwrite an existing step
                # (save() returns False), leaving the old run's state for a later resume.
                for step in manager.all_steps():
                    manager.delete(step)
        if runner is None:
            runner = init(keys, hparams)
        if out is not None and primary:
            run_record.write_run_info(out, config, seeds, checker, sweep)
            io.write_jsonl(out / checkpoint.METRICS, records)

        bar = _progress(
            config.num_chunks, done_chunks, progress and primary, desc or config.reward_mode
        )
        stop = (
            config.num_chunks
            if max_chunks is None
            else min(config.num_chunks, done_chunks + max_chunks)
        )
        for c in range(done_chunks, stop):
            if cancel is not None and cancel.is_set():
                raise Cancelled(f"stopped before chunk {c + 1}; {checkpoint.kept(manager, out)}")
            new_runner, metrics, finite = chunk(runner)
            metrics, finite = to_host(metrics), to_host(finite)
            if not finite.all():
                bad = [idents[i] for i in np.flatnonzero(~finite)]
                bad = [i[0] for i in bad] if not sweep else [_name(i, sweep) for i in bad]
                raise NonFiniteError(
                    f"non-finite loss or parameters within updates {c * config.eval_every + 1}-"
                    f"{(c + 1) * config.eval_every} (seeds {bad}); {checkpoint.kept(manager, out)}"
                )
            runner = new_runner
            totals += metrics["train"]["violations"].sum(axis=1).astype(np.int64)
            cost_totals += metrics["train"]["env_cost"].astype(np.float64).sum(axis=1)
            new = chunk_records(config, c, seeds, metrics, totals, swept, cost_totals)
            records.extend(new)
            if out is not None and primary:
                io.append_jsonl(out / checkpoint.METRICS, new)
            last = c + 1 == config.num_chunks
            if manager is not None and ((c + 1) % checkpoint_every == 0 or last):
                checkpoint.save(manager, c + 1, runner, out, records, primary)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(
                    viol=f"{np.mean([r['eval/violation_rate'] for r in new]):.2f}",
                    succ=f"{np.mean([r['eval/success_rate'] for r in new]):.2f}",
                )
        if out is not None and jax.process_count() > 1:
            # No process leaves (and, say, resumes) before process 0 has written its files.
            multihost_utils.sync_global_devices("agents.runner.run: files written")
    finally:
        if bar is not None:
            bar.close()
        if manager is not None:
            manager.close()

    result = _collect(config, idents, records, ident)
    result["seeds"] = seeds
    if sweep:
        result["sweep"] = {n: np.asarray(v) for n, v in swept.items()}
    result["params"] = runner.params
    result["runner"] = runner
    result["complete"] = stop == config.num_chunks
    if final_episodes:
        final = programs.executable("final", len(seeds), final_episodes)
        result["final"] = to_host(final(runner.params, runner.hparams))
        result["final_episodes"] = final_episodes
    result["wall_s"] = time.perf_counter() - start
    return result


# ----------------------------------------------------------------------------------------
def _upgrade(env, saved: dict) -> dict | None:
    """A checkpoint of an older layout (``saved``, as orbax reads it) in today's: the env
    states' extras through the env's ``upgrade_extras``; None when it knows no older one."""
    state = saved.get("env", {}).get("state") if isinstance(saved.get("env"), dict) else None
    if not isinstance(env, ConstrainedEnvironment) or not isinstance(state, dict):
        return None
    if not isinstance(state.get("extras"), dict):
        return None
    extras = env.upgrade_extras(state.get("extras"), state.get("grid"))
    if extras is None:
        return None
    state = {**state, "extras": checkpoint.stored(extras)}
    return {**saved, "env": {**saved["env"], "state": state}}


def _agents(sweep: Mapping[str, Sequence[float]], seeds: list[int]) -> tuple[dict, list]:
    """The agents of a run, ordered by swept values (the first name outermost), then seed:
    ``({name: value per agent}, [(seed, *values) per agent])``."""
    grid = list(itertools.product(*sweep.values()))  # [()] without a sweep
    swept = {n: [v[j] for v in grid for _ in seeds] for j, n in enumerate(sweep)}
    return swept, [(s, *v) for v in grid for s in seeds]


def _ident(record: dict, names: tuple = ()) -> tuple:
    """The agent a record belongs to: its seed and swept values."""
    return (record["seed"], *(record[n] for n in names))


def _name(ident: tuple, sweep: Mapping) -> str:
    values = [f"{n}={v}" for n, v in zip(sweep, ident[1:], strict=True)]
    return ", ".join([f"seed {ident[0]}", *values])


#: The evaluation metrics of the records that a run's result gathers per agent and chunk.
_EVAL_KEYS = ("eval/violation_rate", "eval/mean_reward", "eval/success_rate", "eval/mean_cost",
             "eval/mean_costly_run", "eval/max_costly_run")  # fmt: skip


def _collect(config: PPOConfig, seeds: list[tuple], records: list[dict], ident=_ident) -> dict:
    """Per-agent histories; ``seeds`` are the agents' :func:`_ident` tuples."""
    chunks = sorted({r["chunk"] for r in records})
    by = {(ident(r), r["chunk"]): r for r in records}

    def history(key):
        """(agents, chunks) values of ``key``, or None where a record lacks one (a resumed run
        directory older than the metric)."""
        values = [[by[s, c].get(key) for c in chunks] for s in seeds]
        return None if any(v is None for row in values for v in row) else np.array(values)

    evaluation = {k.split("/")[1]: history(k) for k in _EVAL_KEYS}
    evaluation = {k: v for k, v in evaluation.items() if v is not None}
    last = chunks[-1] if chunks else None
    cost_rate = history("train/cum_env_cost_rate")
    costs = {}
    if cost_rate is not None and chunks:
        costs = {
            "train_cost_rate": cost_rate,
            "train_env_cost": np.array([by[s, last]["train/cum_env_cost"] for s in seeds]),
        }
    return {
        "steps": np.array([(c + 1) * config.eval_every * config.batch_size for c in chunks]),
        "eval": evaluation,
        "train_violations": np.array(
            [by[s, last]["train/cum_violations"] if last is not None else 0 for s in seeds]
        ),
        "train_violations_early": np.array(
            [sum(by[s, c].get("train/violations_early", 0) for c in chunks) for s in seeds]
        ),
        "train_alarms": np.array([sum(by[s, c]["train/alarms"] for c in chunks) for s in seeds]),
        **costs,
        "records": records,
        "seeds": seeds,
    }


def _progress(total, initial, enabled, desc):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit="chunk", dynamic_ncols=True)


def load_agents(out_dir: str | os.PathLike, checker=None) -> dict:
    """The trained agents of a directory that :func:`run` wrote, from its newest verified
    checkpoint, without training or compiling anything (nothing in the directory changes).

    ``checker``: the one the run was trained with, required by the checker modes and checked
    against the run's record. Returns ``config`` (:class:`PPOConfig`), ``learner``,
    ``seeds`` and ``hparams`` (one entry per agent; swept values as arrays), ``params``
    (stacked over agents), ``chunks`` (chunks done) and ``complete``.
    """
    out = Path(out_dir)
    info = run_record.read_run_info(out)
    if not (out / "checkpoints").is_dir():
        raise ValueError(f"{out / 'checkpoints'}: no checkpoint")
    config = run_record.saved_config(info)
    if run_record.checker_sha256(checker) != info.get("checker_sha256"):
        raise ValueError(f"{out}: the run was trained with "
                         f"{'another checker' if info.get('checker_sha256') else 'no checker'}"
                         f"{'' if checker is not None else ' (pass its checker)'}")  # fmt: skip
    sweep = check_sweep(info.get("sweep"), config)
    seeds = [int(s) for s in info["seeds"]]  # one per agent, as run() records them
    per_value = len(seeds) // len(list(itertools.product(*sweep.values())))
    swept, _ = _agents(sweep, seeds[:per_value])
    hparams = {n: jnp.asarray(v, jnp.float32) for n, v in swept.items()}
    learner = make_learner(config, checker)
    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    abstract = jax.eval_shape(jax.vmap(learner.init), keys, hparams)
    manager = checkpoint.make_manager(out / "checkpoints")
    chunks = checkpoint.verified_step(manager, out, delete=False)
    upgrade = functools.partial(_upgrade, learner.env)
    state = checkpoint.restore(manager, chunks, abstract, None, upgrade)
    return {"config": config, "learner": learner, "seeds": seeds, "hparams": hparams,
            "params": state.params, "chunks": chunks,
            "complete": chunks == config.num_chunks}  # fmt: skip
