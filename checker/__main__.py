"""``python -m checker``: train a checker of either kind and measure it.

::

    python -m checker --env TwoRooms-v0 --out DIR [--samples 12000 --window 5 --lookahead 1
        --seed 0 --epochs 60 --counterfactuals 1 --distractors 0.5 ...]
    python -m checker --kind memory --json runs/memory_checker.json [--out DIR --lookahead 0 ...]

``--kind window`` (the default, :class:`CheckerRun`) collects ``--samples`` balanced windows
with the noisy oracle on the env's *train* language split, trains with
:func:`checker.train_checker` (which splits off ``--test-fraction`` of them as the test set),
writes ``DIR/params.msgpack`` + ``DIR/config.json`` (:func:`checker.load` restores it;
``config.json`` holds the parameters' sha256) and ``DIR/metrics.json`` (with the same sha256,
so a report names the parameters it measured): test split, held-out language split
(``jaxgrid.make(env, split="heldout")``), lead time on full episodes and, for TwoRooms
checkers, transfer to ThreeRoomsKey-v0. It prints a summary and the wall times.

``--kind memory`` (:class:`MemoryRun`; ``python -m checker.memory`` is the same command)
collects whole streams of ``BatchedAutoReset(HazardRooms)`` under a random behaviour policy
(:func:`checker.data.collect_streams`), trains the recurrent checker through each stream
(:func:`checker.train_memory_checker`) and reports, on fresh streams of the train and held-out
splits, AUROC overall, per constraint type, and on the budget episodes whose violation comes
more than ``--late`` steps after the first costly event, which no window of ``--late``
frames can count (:func:`checker.metrics.evaluate_streams`); ``--json`` writes the report,
``--out DIR`` saves the checker.

``DIR`` must be new or empty; ``--overwrite`` first removes an earlier checker's files there,
so no stale report survives a retrained checker. ``--help`` lists every flag of the kind with
its default.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import inspect
import json
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import jax

import jaxgrid
from checker import cli
from checker.data import collect, collect_episodes, collect_streams, relabel
from checker.memory_model import MemoryCheckerConfig, TrainedMemoryChecker
from checker.metrics import evaluate, evaluate_streams, predict_streams
from checker.policies import NoisyOracleParams, noisy_oracle_policy
from checker.protocol import KINDS
from checker.store import check_writable_file, fresh_checker_dir, params_sha256, save
from checker.train import (
    CheckerTrainConfig,
    MemoryTrainConfig,
    check_window_scenario,
    fit_memory_checker,
    train_checker,
)
from jaxgrid.io import write_json
from jaxgrid.rundir import lock

PROG = "python -m checker"
Kind = Literal["window", "memory"]

PAPER_SAMPLES = {"TwoRooms-v0": 12_000, "TwoRoomsLava-v0": 15_000}
TRANSFER_TARGET = "ThreeRoomsKey-v0"


@dataclasses.dataclass(frozen=True)
class CheckerRun:
    """Collect windows with the noisy oracle, train a checker on them and measure it."""

    out: str  # the checker's directory: new, empty, or (with --overwrite) an earlier checker's
    # the checker's kind: window (these flags) or memory (`--kind memory --help` lists its own)
    kind: Kind = "window"
    env: str = "TwoRooms-v0"  # the environment id whose windows are collected
    samples: int = 0  # windows collected; 0: the paper's size (15k TwoRoomsLava-v0, else 12k)
    num_envs: int = 256  # parallel envs of every collection
    heldout_samples: int = 3000  # windows of the held-out language split (0: none)
    transfer_samples: int = 3000  # windows of ThreeRoomsKey-v0 for a TwoRooms checker (0: none)
    episode_envs: int = 64  # envs of the full episodes that measure the lead time
    episode_steps: int = 256  # steps of those episodes (0: none)
    progress: bool = True  # show progress bars
    overwrite: bool = False  # clear a checker directory given as --out first (else refused)
    oracle: NoisyOracleParams = NoisyOracleParams()  # the behaviour policy (salt: --seed)
    train: CheckerTrainConfig = CheckerTrainConfig()  # every training setting

    def __post_init__(self):
        if self.kind != "window":
            raise ValueError(f"CheckerRun.kind {self.kind!r}: CheckerRun trains a window "
                             "checker, MemoryRun a memory checker")  # fmt: skip
        if not self.out:
            raise ValueError("CheckerRun.out: an output directory is required")
        if os.path.exists(self.out) and not os.path.isdir(self.out):
            raise ValueError(f"CheckerRun.out {self.out} is a file, not a directory")
        if self.env not in jaxgrid.registered_ids():
            raise ValueError(f"CheckerRun.env: unknown environment id {self.env!r}")
        why = "its noisy oracle plans around that door and lava, and labels windows by them"
        try:
            check_window_scenario(self.env, "python -m checker", why)
        except ValueError as e:
            raise ValueError(f"CheckerRun.env {e}") from None
        minimum = {"samples": 0, "num_envs": 1, "heldout_samples": 0, "transfer_samples": 0,
                   "episode_envs": 1, "episode_steps": 0}  # fmt: skip
        for name, low in minimum.items():
            if getattr(self, name) < low:
                raise ValueError(f"CheckerRun.{name} must be >= {low}, got {getattr(self, name)}")
        s, samples = self.train, self.samples_used
        if s.training_rows(samples) < s.batch_size:
            raise ValueError(
                f"CheckerRun.samples {samples} leaves {s.training_rows(samples)} windows to train "
                f"on after CheckerTrainConfig.test_fraction {s.test_fraction} and "
                f"CheckerTrainConfig.val_fraction {s.val_fraction}, fewer than "
                f"CheckerTrainConfig.batch_size {s.batch_size}: raise the first or lower the last"
            )

    @property
    def samples_used(self) -> int:
        """``samples``, or the paper's size for ``env`` when it is 0."""
        return self.samples or PAPER_SAMPLES.get(self.env, 12_000)


@dataclasses.dataclass(frozen=True)
class MemoryRun:
    """Train the recurrent checker on HazardRooms streams; AUROC per type. --label next|into,
    the former name of --lookahead, is read as --lookahead 1|0."""

    kind: Kind = "memory"  # the checker's kind: memory (these flags) or window
    train: MemoryTrainConfig = MemoryTrainConfig()  # streams (--envs) and training
    late: int = 10  # steps that make a violation late
    memory: bool = True  # False (--no-memory): zero the memory at every frame (the ablation)
    actions: bool = False  # read the action into each frame beside it
    json: str | None = None  # write the report here
    out: str | None = None  # save the checker here: new, empty, or (--overwrite) a checker's
    overwrite: bool = False  # clear an earlier checker's files from --out first (else refused)

    def __post_init__(self):
        if self.kind != "memory":
            raise ValueError(f"MemoryRun.kind {self.kind!r}: MemoryRun trains a memory "
                             "checker, CheckerRun a window checker")  # fmt: skip
        if self.late < 1:
            raise ValueError(f"MemoryRun.late must be at least 1, got {self.late}")
        if self.json is not None:
            check_writable_file(self.json, "MemoryRun.json")
        if self.out is not None and (not self.out or Path(self.out).is_file()):
            raise ValueError(f"MemoryRun.out {self.out!r} is not a directory")


@dataclasses.dataclass(frozen=True)
class Command:
    """One kind's command line: the config its flags fill (with the flags' renames) and the
    work done with it, ``work(args, prog) -> report``."""

    config: type
    names: cli.Names
    work: Callable[[Any, str], dict]


def parse(argv: Sequence[str] | None = None, prog: str = PROG):
    """The flags of ``--kind`` (default ``window``): :class:`CheckerRun` (with the oracle's
    and :class:`CheckerTrainConfig`'s) or :class:`MemoryRun` (with :class:`MemoryTrainConfig`'s;
    ``--label next|into`` read as ``--lookahead 1|0``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    pre = argparse.ArgumentParser(prog=prog, add_help=False, allow_abbrev=False)
    pre.add_argument("--kind", choices=KINDS, default="window")
    kind = pre.parse_known_args(argv)[0].kind
    if kind == "memory":
        argv = cli.label_flags(argv, "--label", "--lookahead", prog)
    command = COMMANDS[kind]
    return cli.parse(command.config, argv, prog=prog, names=command.names,
                     description=inspect.cleandoc(command.config.__doc__))  # fmt: skip


def main(argv: Sequence[str] | None = None, prog: str = PROG) -> dict:
    """Run ``python -m checker`` with ``argv`` (default ``sys.argv[1:]``); returns the report.

    Bad flags (and an unwritable ``--json``) exit with status 2 before anything compiles.
    ``--out`` is locked for the run (:func:`jaxgrid.rundir.lock`); before any work, a second
    process on it gets :class:`~jaxgrid.rundir.LockHeld`, and a non-empty ``--out`` without
    ``--overwrite`` (or one that is not a checker directory) a ``ValueError``
    (:func:`checker.store.fresh_checker_dir`): the command exits with status 2 on both, and
    with 130 at once on Ctrl-C (:func:`checker.cli.run_main`).
    """
    args = parse(argv, prog)
    with lock(args.out, prog) if args.out else contextlib.nullcontext():
        if args.out:
            fresh_checker_dir(args.out, args.overwrite)
        return COMMANDS[args.kind].work(args, prog)


def _row(name: str, m: dict | None) -> str:
    if m is None:
        return f"{name:<28} (not run)"

    def fmt(x):
        return "   -  " if x is None else f"{x:6.3f}"

    keys = ("auroc", "f1", "accuracy", "precision", "recall", "ece")
    return f"{name:<28} {m['n']:>6} " + " ".join(fmt(m.get(k)) for k in keys)


def run_window(args: CheckerRun, prog: str = PROG) -> dict:
    """Collect noisy-oracle windows, train a window checker, save it in ``args.out``, measure
    it there (``metrics.json``) and print a summary; returns the report."""
    settings = args.train
    samples = args.samples_used
    policy = dataclasses.replace(args.oracle, salt=settings.seed)
    key = jax.random.PRNGKey(settings.seed)
    k_data, k_held, k_trans, k_ep = jax.random.split(key, 4)

    def windows(env_id, key, n, split="train"):
        env = jaxgrid.make(env_id, split=split)
        return collect(env, noisy_oracle_policy, policy, key, n, settings.window,
                       settings.lookahead, args.num_envs, env_id=env_id,
                       final_windows=settings.final_windows)  # fmt: skip

    t0 = time.perf_counter()
    data = windows(args.env, k_data, samples)
    t_collect = time.perf_counter() - t0
    trained, history, test = train_checker(data, settings, progress=args.progress)
    jax.block_until_ready(trained.params)
    t_train_done = time.perf_counter()
    save(trained, args.out)
    digest = params_sha256(args.out)

    metrics = {"test": evaluate(trained, test) if test is not None else None}
    t_eval0 = time.perf_counter()
    if args.heldout_samples:
        held = windows(args.env, k_held, args.heldout_samples, "heldout")
        metrics["heldout_language"] = evaluate(trained, held)
    if args.episode_steps:
        eps = collect_episodes(jaxgrid.make(args.env), noisy_oracle_policy, policy, k_ep,
                               args.episode_steps, settings.window, settings.lookahead,
                               args.episode_envs, env_id=args.env)  # fmt: skip
        metrics["full_episodes"] = evaluate(trained, eps)
    if args.transfer_samples and args.env.startswith("TwoRooms"):
        trans = windows(TRANSFER_TARGET, k_trans, args.transfer_samples)
        metrics[f"transfer_{TRANSFER_TARGET}"] = evaluate(trained, trans)
    t_end = time.perf_counter()

    report = {
        "args": dataclasses.asdict(args),
        "samples": samples,
        "dataset": data.meta,
        "split_sizes": {"trainval": len(data) - history["test_rows"], "test": history["test_rows"]},
        "history": history,
        "timing_s": {
            "collect": t_collect,
            "train": t_train_done - t0 - t_collect,
            "collect_plus_train": t_train_done - t0,
            "extra_collection_and_eval": t_end - t_eval0,
            "total": t_end - t0,
            "devices": [str(d) for d in jax.devices()],
            "cpu_count": os.cpu_count(),
        },
        "metrics": metrics,
        "params_sha256": digest,  # the parameters measured here (checked by --checker reuse)
    }
    write_json(os.path.join(args.out, "metrics.json"), report)

    print(f"checker for {args.env} (window {settings.window}, lookahead {settings.lookahead}, "
          f"seed {settings.seed}) -> {args.out}")  # fmt: skip
    print(f"data: {len(data)} windows, positive fraction {data.positive_fraction:.3f}, natural "
          f"positive rate {data.meta['natural_positive_rate']:.4f}, "
          f"{data.meta['steps_per_env']} steps x {args.num_envs} envs")  # fmt: skip
    best = history["best_val_loss"]
    print(f"training: {history['epochs_run']} epochs, best epoch {history['best_epoch']}, "
          f"best val loss {'-' if best is None else f'{best:.4f}'}")  # fmt: skip
    print(f"{'split':<28} {'n':>6} {'AUROC':>6} {'F1':>6} {'acc':>6} {'prec':>6} {'recall':>6} "
          f"{'ECE':>6}")  # fmt: skip
    for name, m in metrics.items():
        print(_row(name, m))
    lt = (metrics.get("full_episodes") or {}).get("lead_time")
    if lt:
        print(f"lead time (full episodes, thr {lt['threshold']}): {lt['violating_episodes']} "
              f"violating episodes, detected before {lt['detected_before']}, mean lead "
              f"{lt['mean_lead_time']}, false-alarm rate {lt['false_alarm_rate']}")  # fmt: skip
    tm = report["timing_s"]
    print(f"wall time: collect {tm['collect']:.1f} s + train {tm['train']:.1f} s = "
          f"{tm['collect_plus_train']:.1f} s; extra collection + eval "
          f"{tm['extra_collection_and_eval']:.1f} s; total {tm['total']:.1f} s "
          f"({tm['cpu_count']} CPUs, {tm['devices']})")  # fmt: skip
    return report


def run_memory(
    env_id: str = "HazardRooms-v0",
    num_envs: int | None = None,
    num_steps: int | None = None,
    config: MemoryCheckerConfig | None = None,
    train: MemoryTrainConfig | None = None,
    splits: Sequence[str] = ("train", "heldout"),
    late: int = 10,
    progress: bool = False,
    out: str | None = None,
) -> dict:
    """Collect streams on the train split, train, and evaluate on fresh streams of each of
    ``splits`` (other seeds). The report holds the settings (``checker_config``,
    ``train_config``), one :func:`evaluate_streams` entry per split and the wall seconds.
    ``num_envs`` and ``num_steps`` (None: ``train.streams`` and ``train.steps``) size each
    split's streams; with ``out`` the trained checker is saved there (:func:`checker.save`)."""
    config = config or MemoryCheckerConfig()
    train = train or MemoryTrainConfig()
    num_envs = train.streams if num_envs is None else num_envs
    num_steps = train.steps if num_steps is None else num_steps
    t0 = time.perf_counter()
    data = collect_streams(
        jaxgrid.make(env_id), jax.random.PRNGKey(train.seed), num_envs, num_steps, train.guided
    )
    data = relabel(data, train.lookahead)
    params, losses = fit_memory_checker(
        data, config, train, "train memory checker" if progress else None
    )
    if out is not None:
        save(TrainedMemoryChecker(params=params, config=config, env_id=env_id,
                                  lookahead=train.lookahead), out)  # fmt: skip
    report = {
        "env_id": env_id,
        "num_envs": num_envs,
        "num_steps": num_steps,
        "checker_config": dataclasses.asdict(config),
        "train_config": dataclasses.asdict(train),
        "train_positives": int(data["label"].sum()),
        "final_loss": float(losses[-50:].mean()),
    }
    for split in splits:
        env = jaxgrid.make(env_id, split=split)
        test = collect_streams(
            env, jax.random.PRNGKey(train.seed + 1000), num_envs, num_steps, train.guided
        )
        test = relabel(test, train.lookahead)
        report[split] = evaluate_streams(
            predict_streams(params, config, test), test, late, train.lookahead
        )
    report["wall_s"] = time.perf_counter() - t0
    return report


def run_memory_command(args: MemoryRun, prog: str = PROG) -> dict:
    """:func:`run_memory` with ``args``' settings; prints the AUROCs, writes ``--json``."""
    t = args.train
    print(f"{prog}: {t.streams} streams x {t.steps} frames of HazardRooms-v0, {t.updates} "
          "updates", file=sys.stderr, flush=True)  # fmt: skip
    report = run_memory(config=MemoryCheckerConfig(memory=args.memory, actions=args.actions),
                        train=t, late=args.late, progress=True, out=args.out)  # fmt: skip
    print(json.dumps({k: report[k] for k in ("train", "heldout") if k in report}, indent=1))
    if args.json:
        write_json(args.json, report)
    return report


COMMANDS = {
    "window": Command(CheckerRun, {NoisyOracleParams: {"salt": None}}, run_window),
    "memory": Command(MemoryRun, {MemoryTrainConfig: {"streams": "envs"}}, run_memory_command),
}


if __name__ == "__main__":
    cli.run_main(main, PROG)
