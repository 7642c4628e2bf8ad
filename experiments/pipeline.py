"""The paper's experiment, end to end, shared by every scenario module.

``python -m experiments.two_rooms`` (and ``two_rooms_lava``, ``three_rooms_key``) calls
:func:`main`, which runs these phases; each one leaves its artefact in ``--out`` and is
skipped when the artefact is already there, so an interrupted run resumes where it stopped:

a. **behaviour** agent: PPO in ``none`` mode for ``behaviour_steps`` on the checker's
   scenario (the paper's "partially trained agent"), ``DIR/behaviour/``;
b. **data**: windows of its rollouts with random constraints, labelled by the ground-truth
   monitor ``lookahead`` steps ahead (1 = just before), ``DIR/checker_data.{npz,json}``;
c. **checker**: trained by :func:`checker.train_checker` and measured (test split, held-out
   language split, and for a checker of another scenario, transfer), ``DIR/checker/`` and
   ``DIR/checker.json``;
d. **PPO** in every reward mode over ``seeds`` seeds at once (vmapped), evaluated on fixed
   seeds every ``eval_every`` updates, checkpointed, ``DIR/modes/<mode>/``;
e. **final evaluation** over ``final_episodes`` fixed-seed episodes per seed (the shield
   modes twice: with the shield, and the policy alone);
f. **report**: ``results.json``, ``results.md``, ``curves.png``, ``episodes.gif``,
   ``metrics.jsonl`` and ``config.json``; interquartile means over seeds with stratified
   bootstrap intervals (:mod:`experiments.stats`).

One process writes into ``--out`` at a time (``--out/.lock``). Every file is written to a
temporary name and renamed; parameter files carry a sha256 in their JSON sidecar. A damaged
artefact makes its phase redo its work, with a message (each phase is deterministic, and the
phases after it check the checksum of what they were made from), or stops the run with exit
status 2 and a message naming the file.

An :class:`ExperimentConfig` holds the experiment's own sizes, the compared agents'
:class:`~agents.config.PPOConfig` and the checker's :class:`~checker.train.CheckerTrainConfig`
(or :class:`~checker.memory.MemoryTrainConfig`); each validates its own fields, and their
defaults are the experiments' settings. An experiment is a row of
:data:`experiments.presets.EXPERIMENTS`, which names what it changes; the presets
(``--quick``, the default, ``--paper``) are :data:`experiments.presets.PRESETS`, and
:func:`preset` makes the configuration of a row in a preset. The command line is generated
from the dataclasses (:mod:`checker.cli`); ``--help`` lists every flag and its default.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import shlex
import sys
import time
from pathlib import Path
from typing import Annotated

from tyro.constructors import PrimitiveConstructorSpec

from agents.config import (
    COST_SOURCES,
    PAPER_MODES,
    REWARD_MODES,
    PPOConfig,
    check_sweep,
    either_source,
)
from checker import cli
from checker.train import CheckerTrainConfig, MemoryTrainConfig
from experiments import assembly, checker_phases, phases, scheduling
from experiments.presets import PRESETS, Experiment
from jaxgrid import rundir

CHECKER_KINDS = tuple(checker_phases.CHECKER_PHASES)


def _is_share(x) -> bool:
    """``x`` is a number (not a bool) in [0, 1]."""
    return not isinstance(x, bool) and isinstance(x, int | float) and 0 <= x <= 1


def _modes(args: list[str]) -> tuple[str, ...]:
    return tuple(m.strip() for m in args[0].split(",") if m.strip())


# ``--modes checker,none``
Modes = Annotated[tuple[str, ...], PrimitiveConstructorSpec(
    nargs=1, metavar="MODE[,MODE...]", instance_from_str=_modes,
    is_instance=lambda x: isinstance(x, tuple), str_from_instance=lambda m: [",".join(m)],
)]  # fmt: skip


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """One experiment; every part is validated on construction (``ValueError``)."""

    experiment: str = "two_rooms"  # the row of experiments.presets: names the outputs (no flag)
    checker_env_id: str | None = None  # the checker's scenario; None: the agents' (no flag)
    out: str | None = None  # output directory; None: runs/<experiment>/<date-time>
    checker: str | None = None  # a trained checker's directory, reused (skips phases a-c)
    modes: Modes = PAPER_MODES  # the reward modes compared (any of REWARD_MODES)
    # the cost of the modes that can learn from either source (lagrangian, pid_lagrangian,
    # saute, cpo, focops): "checker", its alarms (the paper's idea), or "monitor", the
    # ground-truth cost (the safe-RL convention); None: each mode's own (the checker's)
    constrained_cost: str | None = None
    seeds: int = 5  # agents per mode, trained at once: seeds --seed, --seed + 1, ...
    # NAME=V1,V2,...: every seed runs with every value, all in one compiled program per mode
    # (NAME: penalty, checker_threshold, cost_limit, ent_coef or lr); results per value
    sweep: str | None = None
    behaviour_steps: int = 300_000  # env steps of the behaviour agent (phase a)
    checker_samples: int = 12_000  # windows of checker data (phase b)
    # steps per env at most while collecting until half the windows are positives (phase b)
    collect_max_steps: int = 4096
    # probability of a uniformly random action in place of the behaviour agent's, at each
    # step of the collection (phase b): a trained agent seldom takes the rare steps (into
    # lava) that the checker must learn to recognise
    collect_epsilon: float = 0.2
    curve_points: int = 15  # evaluations: every max(1, updates // curve_points) updates
    final_episodes: int = 500  # final evaluation episodes per agent
    gif_episodes: int = 4  # episodes recorded in episodes.gif (0: none)
    quick: bool = False  # the smoke-test preset: every output in minutes, results mean nothing
    paper: bool = False  # the paper's preset: 1e7 steps, 10 seeds
    progress: bool = True  # show progress bars
    # phases that train at once, in threads (the checker's phases and the modes): on a
    # 2-core CPU two programs fill XLA's thread pool better than one, 1.2-1.4x sooner than
    # one after the other, with the same results; 1: one at a time
    workers: int = 2
    # time the PureJaxRL-style baseline learner (agents.baseline) for ~30 s at the
    # end, and print its steps/s beside the run time: run times differ between machines
    machine_baseline: bool = True
    # The compared agents' PPO (--steps: total_timesteps), PPOConfig's defaults. Each run
    # sets reward_mode and eval_every (from curve_points; 1 here lets any step budget
    # validate); the behaviour agent runs on checker_env_id for behaviour_steps.
    ppo: PPOConfig = PPOConfig(eval_every=1)
    # The checker's training (--checker-*): from --seed, and measured at the threshold at
    # which the agents' checker alarms (--checker-threshold).
    checker_train: CheckerTrainConfig = CheckerTrainConfig()
    # "window": phases a-c above (the paper's); "memory": a recurrent checker trained on
    # streams of the agents' env under a random policy, for constraints that count
    # (experiments.checker_phases.CHECKER_PHASES; no flag, the row sets it)
    checker_kind: str = "window"
    # The memory checker's data and training (--memory-*; checker_kind "memory" only)
    memory_checker: MemoryTrainConfig = MemoryTrainConfig()
    # The shield's own memory checker: trained as --memory-* say, but with this share of
    # oracle actions in its streams (--memory-guided); None: the shield uses the experiment's
    # checker. A shield pays for each false alarm with success, so it wants streams that go
    # where trained agents go; a penalty wants the late budget violations that the random
    # streams hold more of (docs/decisions.md). --checker replaces the other checker only.
    shield_guided: float | None = None
    # The memory checkers read the action into each frame beside it: a turn and a step
    # forward can show the same cells, and only the step enters one (docs/decisions.md)
    checker_actions: bool = False

    def __post_init__(self):
        if self.checker_env_id is None:
            object.__setattr__(self, "checker_env_id", self.ppo.env_id)
        synced = dataclasses.replace(self.checker_train, seed=self.ppo.seed,
                                     threshold=self.ppo.checker_threshold)  # fmt: skip
        object.__setattr__(self, "checker_train", synced)
        synced = dataclasses.replace(self.memory_checker, seed=self.ppo.seed)
        object.__setattr__(self, "memory_checker", synced)
        me = type(self).__name__
        if self.checker_kind not in CHECKER_KINDS:
            raise ValueError(f"{me}.checker_kind must be one of {CHECKER_KINDS}, got "
                             f"{self.checker_kind!r}")  # fmt: skip
        if self.quick and self.paper:
            raise ValueError(f"{me}.quick and {me}.paper exclude each other")
        unknown = [m for m in self.modes if m not in REWARD_MODES]
        if unknown or not self.modes or len(set(self.modes)) < len(self.modes):
            raise ValueError(f"{me}.modes: unknown, repeated or no mode(s) in {self.modes}; "
                             f"choose from {','.join(REWARD_MODES)}")  # fmt: skip
        if self.ppo.cost_source is not None:
            raise ValueError(f"PPOConfig.cost_source is set per mode in an experiment: use "
                             f"{me}.constrained_cost (--constrained-cost)")  # fmt: skip
        if self.constrained_cost is not None:
            if self.constrained_cost not in COST_SOURCES:
                raise ValueError(f"{me}.constrained_cost must be None or one of {COST_SOURCES}, "
                                 f"got {self.constrained_cost!r}")  # fmt: skip
            if not any(either_source(m) for m in self.modes):
                raise ValueError(
                    f"{me}.constrained_cost={self.constrained_cost!r}: no mode of "
                    f"{','.join(self.modes)} can learn from either source (those that can: "
                    f"{','.join(m for m in REWARD_MODES if either_source(m))})"
                )
        positive = ("seeds", "behaviour_steps", "checker_samples", "collect_max_steps",
                    "curve_points", "final_episodes", "workers")  # fmt: skip
        for name in positive + ("gif_episodes",):
            value, low = getattr(self, name), int(name in positive)
            if not isinstance(value, int) or isinstance(value, bool) or value < low:
                raise ValueError(f"{me}.{name} must be an integer >= {low}, got {value!r}")
        guided = self.shield_guided
        if guided is not None:
            if not _is_share(guided):
                raise ValueError(f"{me}.shield_guided must be None or a share in [0, 1], got "
                                 f"{guided!r}")  # fmt: skip
        if not isinstance(self.checker_actions, bool):
            raise ValueError(f"{me}.checker_actions must be a bool, got {self.checker_actions!r}")
        eps = self.collect_epsilon
        if not _is_share(eps):
            raise ValueError(f"{me}.collect_epsilon must be a number in [0, 1], got {eps!r}")
        if self.sweep is not None:
            self.sweep_values  # noqa: B018 (validates)
        if self.out is not None and not self.out:
            raise ValueError(f"{me}.out: an output directory is required (omit the flag for "
                             "runs/<experiment>/<date-time>)")  # fmt: skip
        if self.out and os.path.exists(self.out) and not os.path.isdir(self.out):
            raise ValueError(f"{me}.out {self.out}: not writable, it is a file (an output "
                             "directory is needed)")  # fmt: skip
        checker_phases.CHECKER_PHASES[self.checker_kind].check(self)
        if not self.checker_train.test_fraction > 0:
            raise ValueError("CheckerTrainConfig.test_fraction must be > 0 in an experiment: "
                             "its report holds the checker's test metrics")  # fmt: skip
        import jaxgrid

        for name, env_id in (("PPOConfig.env_id", self.env_id),
                             (f"{me}.checker_env_id", self.checker_env_id)):  # fmt: skip
            if env_id not in jaxgrid.registered_ids():
                raise ValueError(f"{name}: unknown environment id {env_id!r}")
        if self.checker is not None and not (Path(self.checker) / "config.json").exists():
            raise ValueError(f"{me}.checker {self.checker}: no trained checker there "
                             "(expected config.json and params.msgpack)")  # fmt: skip

    @property
    def sweep_values(self) -> dict[str, tuple[float, ...]]:
        """``sweep`` as {name: values} ({} without one); ``ValueError`` naming the flag."""
        if self.sweep is None:
            return {}
        name, sep, values = self.sweep.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError("expected NAME=V1,V2,...")
            return check_sweep({name.strip(): values.split(",")}, self.ppo)
        except ValueError as e:
            raise ValueError(f"{type(self).__name__}.sweep {self.sweep!r}: {e}") from None

    @property
    def env_id(self) -> str:
        """The compared agents' scenario."""
        return self.ppo.env_id

    @property
    def seed(self) -> int:
        """The first seed: of the data, the checker and the first agent of every mode."""
        return self.ppo.seed


BASE = ExperimentConfig()  # the default preset, before a row's env ids and changes


def override(cfg, changes: dict):
    """``cfg`` with ``changes`` (``dataclasses.replace``); a dict changes a nested config."""
    nested = {k: override(getattr(cfg, k), v) for k, v in changes.items() if isinstance(v, dict)}
    return dataclasses.replace(cfg, **{**changes, **nested})


def preset(row: Experiment, name: str = "default") -> ExperimentConfig:
    """The configuration of experiment ``row`` in preset ``name``: :data:`BASE` on the row's
    env ids and checker kind, then the row's changes, the preset's and the row's budget."""
    own = dict(experiment=row.name, checker_env_id=row.checker_env_id,
               checker_kind=row.checker_kind, ppo=dict(env_id=row.env_id))  # fmt: skip
    cfg = override(BASE, own)
    for changes in (row.changes, PRESETS[name], row.budgets.get(name, {})):
        cfg = override(cfg, changes)
    return cfg


def make_checker(cfg: ExperimentConfig, out, keep: dict, cancel, reused=None):
    """Phases a-c, or the reused checker ``reused``: ``(trained checker, its report)``.
    ``keep`` receives the ``behaviour`` agent and the checker ``data`` that phases a-b made;
    ``cancel`` stops the behaviour agent's training at its next checkpoint."""
    if reused is not None:
        return checker_phases.reuse_checker(cfg, reused)
    return checker_phases.CHECKER_PHASES[cfg.checker_kind].make(cfg, out, keep, cancel)


def run_experiment(cfg: ExperimentConfig, keep: dict | None = None) -> dict:
    """Run (or resume) every phase of ``cfg`` and write the outputs; returns ``results``.

    ``keep``, a dict, receives what the phases returned (``behaviour``, ``data``,
    ``trained``, ``report``, ``runs``), for a caller that goes on working with them.
    """
    # a --checker that does not fit is refused before --out records this configuration
    reused = checker_phases.load_reused(cfg) if cfg.checker is not None else None
    out = phases.prepare_out(cfg)  # fails here, before any training, if not writable
    start = time.perf_counter()
    keep = {} if keep is None else keep
    compiler = scheduling.Compiler(cfg)  # the modes' programs compile in a thread meanwhile
    workers = scheduling.Workers(cfg.workers)  # the phases that train, cfg.workers at once
    interrupted = False
    try:
        compiler.submit()  # the modes without a checker, while the checker is made
        made = workers.submit(make_checker, cfg, out, keep, workers.cancel, reused)  # a-c
        own = None  # c': the shield's own checker, beside c
        if cfg.shield_guided is not None and "shield" in cfg.modes:
            own = workers.submit(checker_phases.memory_checker, cfg, out, guided=
                                 cfg.shield_guided, name=checker_phases.SHIELD_CHECKER)  # fmt: skip
        # d, e: the modes without a checker start beside a-c, the others once it is done
        train = lambda mode, trained: workers.submit(  # noqa: E731
            phases.train_agents, cfg, out, mode, trained, compiler, workers.cancel
        )
        jobs = {m: train(m, None) for m in compiler.order}
        trained, checker_report = made.result()
        checkers = {mode: trained for mode in cfg.modes}
        if own is not None:
            checkers["shield"], shield_report = own.result()
            checker_report = dict(checker_report, shield=shield_report)
        compiler.submit(checkers)
        jobs.update({m: train(m, checkers[m]) for m in compiler.order if m not in jobs})
        runs = workers.results({m: jobs[m] for m in cfg.modes})
    except KeyboardInterrupt:
        interrupted = True  # a chunk or a compile in a thread may take a minute: no wait
        raise
    finally:
        workers.close(wait=not interrupted)  # after an error: they stop at their next chunk
        compiler.close()
    keep.update(trained=trained, report=checker_report, runs=runs)
    if cfg.sweep_values:  # one results directory per swept value, and a summary
        return assembly.write_sweep(cfg, out, runs, checker_report, time.perf_counter() - start)
    phases.write_gif(cfg, out, runs, trained)
    results = assembly.assemble(cfg, out, runs, checker_report, time.perf_counter() - start)
    if cfg.machine_baseline:  # after the run, so that it does not delay any phase
        from agents.baseline import machine_baseline

        results["timing"]["machine_baseline"] = machine_baseline()
    paths = assembly.write_outputs(cfg, out, results, runs)  # f
    from experiments.report import summarise

    print(summarise(results))
    print("outputs:\n" + "\n".join(f"  {p}" for p in paths))
    return results


# ----------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------
# Flags of the nested configs: PPO's are their own names, the checker's training ones
# --checker-<name>; None: set by the pipeline, no flag.
FLAGS: cli.Names = {
    # the nested configs' groups in --help (their flags keep the names below)
    ExperimentConfig: {"experiment": None, "checker_env_id": None, "checker_kind": None,
                       "ppo": "PPO", "checker_train": "checker", "memory_checker": "checker"},
    PPOConfig: {"total_timesteps": "steps", "env_id": None, "env_kwargs": None,
                "reward_mode": None, "eval_every": None, "cost_source": None},
    CheckerTrainConfig: {**{f.name: f"checker_{f.name}"
                            for f in dataclasses.fields(CheckerTrainConfig)},
                         "window": "window", "lookahead": "lookahead", "seed": None,
                         "threshold": None},
    MemoryTrainConfig: {**{f.name: f"memory_{f.name}"
                           for f in dataclasses.fields(MemoryTrainConfig)}, "seed": None},
}  # fmt: skip


def hidden_flags(row: Experiment) -> cli.Names:
    """The settings without a flag in ``row``'s command line as :func:`checker.cli.parse`
    names: ``row.hidden`` and the settings only other kinds of checker read
    (:attr:`~experiments.checker_phases.CheckerPhases.settings`); each is a field of
    :class:`ExperimentConfig` (a nested part: every field of it), or ``"part.field"``."""
    parts = {f.name: f.type for f in dataclasses.fields(ExperimentConfig)}
    nested = {"ppo": PPOConfig, "checker_train": CheckerTrainConfig,
              "memory_checker": MemoryTrainConfig}  # fmt: skip
    names: dict = {}
    others = [p.settings for kind, p in checker_phases.CHECKER_PHASES.items()
              if kind != row.checker_kind]  # fmt: skip
    for item in (*row.hidden, *(name for settings in others for name in settings)):
        part, _, field = item.partition(".")
        if part not in parts:
            raise ValueError(f"Experiment {row.name}.hidden: {item!r} names no setting")
        if part in nested:
            cls = nested[part]
            fields = [field] if field else [f.name for f in dataclasses.fields(cls)]
            names.setdefault(cls, {}).update(dict.fromkeys(fields))
        else:
            names.setdefault(ExperimentConfig, {})[part] = None
    return names


def parse_args(argv, row: Experiment):
    """The configuration of ``argv``: experiment ``row`` in the preset ``--quick``/``--paper``
    name (default: the default), then every flag given; ``row.hidden`` has no flag."""
    prog = f"python -m experiments.{row.name}"
    argv = cli.label_flags(sys.argv[1:] if argv is None else argv, "--memory-label",
                           "--memory-lookahead", prog)  # fmt: skip
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    for name in ("quick", "paper"):
        pre.add_argument(f"--{name}", action=argparse.BooleanOptionalAction, default=False)
    chosen, _ = pre.parse_known_args(argv)
    name = "quick" if chosen.quick and not chosen.paper else "paper" if chosen.paper else ""
    hide = hidden_flags(row)
    steps = checker_phases.CHECKER_PHASES[row.checker_kind].steps
    names = {cls: {**FLAGS.get(cls, {}), **hide.get(cls, {})} for cls in FLAGS.keys() | hide}
    return cli.parse(
        ExperimentConfig, argv, default=preset(row, name or "default"), names=names,
        prog=prog, title="experiment",
        description=f"{row.name}: the paper's experiment on {row.env_id} "
        f"({steps}, PPO in every reward mode, report). --quick and --paper change the "
        "defaults shown here.",
    )  # fmt: skip


def default_out(experiment: str) -> str:
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return os.path.join("runs", experiment, stamp)


def main(row: Experiment, argv=None) -> dict | None:
    """Run experiment ``row`` with ``argv`` (default ``sys.argv[1:]``); Ctrl-C keeps finished
    phases for a resume.

    Bad flags exit with status 2 before anything compiles. ``--out`` is locked for the whole
    run (:func:`jaxgrid.rundir.lock`): a second process on it exits with status 2 at once,
    naming the holder. An artefact that is damaged beyond what its phase redoes, or a
    ``--checker`` whose report does not match it, stops the run with status 2 and a message
    naming the file.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    rundir.refuse_held_out(argv)  # a run already writing into --out: refused at once
    cfg = parse_args(argv, row)
    if cfg.quick:  # a smoke test is all compile time: cheaper compiles (LLVM's optimisations
        # off, XLA:CPU's per-op emitters; float results may differ in the last place). XLA
        # reads the flags when the CPU backend starts.
        for flag in ("--xla_backend_optimization_level=0", "--xla_cpu_use_fusion_emitters=false"):
            if flag.split("=")[0] not in os.environ.get("XLA_FLAGS", ""):
                os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip()
    if cfg.out is None:
        cfg = dataclasses.replace(cfg, out=default_out(cfg.experiment))
    try:
        resume = resume_command(cfg.experiment, argv, cfg.out)
        with rundir.lock(cfg.out, f"python -m experiments.{cfg.experiment}", resume):
            return run_experiment(cfg)  # an unwritable or foreign --out fails before training
    except (ValueError, FileNotFoundError, rundir.LockHeld) as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    except OSError as e:  # a failed write (a full disk, a checkpoint orbax could not save)
        print(f"error: {e}\nfinished phases are kept in {cfg.out}; resume with\n  "
              f"{resume_command(cfg.experiment, argv, cfg.out)}", file=sys.stderr)  # fmt: skip
        raise SystemExit(1) from None
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished phases are kept in {cfg.out}; resume with\n  "
              f"{resume_command(cfg.experiment, argv, cfg.out)}", file=sys.stderr)  # fmt: skip
        raise SystemExit(130) from None


def resume_command(experiment: str, argv: list[str], out: str) -> str:
    """The command line that resumes a run of ``argv`` in ``out``: the same flags, and
    ``--out out`` in place of any ``--out`` given."""
    kept, skip = [], False
    for a in argv:
        if skip or a == "--out" or a.startswith("--out="):
            skip = a == "--out"
            continue
        kept.append(a)
    return shlex.join(["python", "-m", f"experiments.{experiment}", *kept, "--out", out])
