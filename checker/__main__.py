"""``python -m checker``: collect windows with the noisy oracle, train a checker, measure it.

::

    python -m checker --env TwoRooms-v0 --out DIR [--samples 12000 --window 5 --lookahead 1
        --seed 0 --epochs 60 --counterfactuals 1 --distractors 0.5 ...]

collects ``--samples`` balanced windows with the noisy oracle on the env's *train* language
split, trains with :func:`checker.train_checker` (which splits off ``--test-fraction`` of them
as the test set), writes ``DIR/params.msgpack`` + ``DIR/config.json`` (:func:`checker.load`
restores it; ``config.json`` holds the parameters' sha256) and ``DIR/metrics.json`` (with the
same sha256, so a report names the parameters it measured): test split, held-out language
split (``jaxgrid.make(env, split="heldout")``), lead time on full episodes and, for TwoRooms
checkers, transfer to ThreeRoomsKey-v0. It prints a summary and the wall times. ``DIR`` must
be new or empty; ``--overwrite`` first removes an earlier checker's files there, so no stale
report survives a retrained checker. ``--help`` lists every flag with its default.
"""

from __future__ import annotations

import dataclasses
import os
import time

import jax

from checker import cli
from checker.policies import NoisyOracleParams
from checker.train import CheckerTrainConfig, check_window_scenario, train_checker

PAPER_SAMPLES = {"TwoRooms-v0": 12_000, "TwoRoomsLava-v0": 15_000}
TRANSFER_TARGET = "ThreeRoomsKey-v0"


@dataclasses.dataclass(frozen=True)
class CheckerRun:
    """Collect windows with the noisy oracle, train a checker on them and measure it."""

    out: str  # the checker's directory: new, empty, or (with --overwrite) an earlier checker's
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
        import jaxgrid

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


def parse(argv=None) -> CheckerRun:
    """The flags: :class:`CheckerRun`'s, the oracle's and :class:`CheckerTrainConfig`'s."""
    return cli.parse(CheckerRun, argv, prog="python -m checker", description=CheckerRun.__doc__,
                     names={NoisyOracleParams: {"salt": None}})  # fmt: skip


def _row(name: str, m: dict | None) -> str:
    if m is None:
        return f"{name:<28} (not run)"

    def fmt(x):
        return "   -  " if x is None else f"{x:6.3f}"

    keys = ("auroc", "f1", "accuracy", "precision", "recall", "ece")
    return f"{name:<28} {m['n']:>6} " + " ".join(fmt(m.get(k)) for k in keys)


def main(argv=None) -> dict:
    """Run ``python -m checker`` with ``argv`` (default ``sys.argv[1:]``); returns the report.

    Bad flags exit with status 2 before anything compiles. ``--out`` is locked for the run
    (:func:`jaxgrid.rundir.lock`); before any work, a second process on it gets
    :class:`~jaxgrid.rundir.LockHeld`, and a non-empty ``--out`` without ``--overwrite`` (or
    one that is not a checker directory) a ``ValueError``
    (:func:`checker.store.fresh_checker_dir`): ``python -m checker`` exits with status 2 on
    both, and with 130 at once on Ctrl-C (:func:`checker.cli.run_main`).
    """
    args = parse(argv)
    from checker.store import fresh_checker_dir
    from jaxgrid.rundir import lock

    with lock(args.out, "python -m checker"):
        fresh_checker_dir(args.out, args.overwrite)
        return _run(args)


def _run(args: CheckerRun) -> dict:
    import jaxgrid
    from checker.data import collect, collect_episodes
    from checker.metrics import evaluate
    from checker.policies import noisy_oracle_policy
    from checker.store import params_sha256, save
    from jaxgrid.io import write_json

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
        "split_sizes": {"trainval": len(data) - history["test_rows"],
                        "test": history["test_rows"]},  # fmt: skip
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


if __name__ == "__main__":
    cli.run_main(main, "python -m checker")
