"""The paper's experiment, end to end, shared by every scenario module.

``python -m experiments.two_rooms`` (and ``two_rooms_lava``, ``three_rooms_key``) calls
:func:`main`, which runs these phases; each one leaves its artefact in ``--out`` and is
skipped when the artefact is already there, so an interrupted run resumes where it stopped:

a. **behaviour** agent: PPO in ``none`` mode for ``behaviour_steps`` on the checker's
   scenario (the paper's "partially trained agent"), ``DIR/behaviour/``;
b. **data**: windows of its rollouts with random constraints, labelled by the ground-truth
   monitor ``lookahead`` steps ahead (1 = just before), ``DIR/checker_data.{npz,json}``;
c. **checker**: trained and measured (test split, held-out language split, and for a checker
   of another scenario, transfer), ``DIR/checker/`` and ``DIR/checker.json``;
d. **PPO** in every reward mode over ``seeds`` seeds at once (vmapped), evaluated on fixed
   seeds every ``eval_every`` updates, checkpointed, ``DIR/modes/<mode>/``;
e. **final evaluation** over ``final_episodes`` fixed-seed episodes per seed;
f. **report**: ``results.json``, ``results.md``, ``curves.png``, ``episodes.gif``,
   ``metrics.jsonl`` and ``config.json``.

Sizes come in three presets: ``--quick`` (smoke test, minutes), the default (meaningful
results in at most about 30 minutes on a 2-core CPU) and ``--paper`` (1e7 steps, 5 seeds).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
import sys
import time
from pathlib import Path

from experiments import phases

MODES = ("checker", "shaped", "none", "lagrangian")


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """One experiment. ``None`` sizes take the preset's value (see :data:`PRESETS`)."""

    experiment: str = "two_rooms"
    env_id: str = "TwoRooms-v0"
    checker_env_id: str | None = None  # scenario the checker is trained on (default env_id)
    out: str | None = None
    checker: str | None = None  # reuse a trained checker directory (skips phases a-c)
    modes: tuple[str, ...] = MODES
    seeds: int | None = None
    steps: int | None = None
    behaviour_steps: int | None = None
    checker_samples: int | None = None
    checker_epochs: int | None = None
    window: int = 5
    lookahead: int = 1
    num_envs: int | None = None
    num_steps: int = 64
    num_minibatches: int = 4
    update_epochs: int = 4
    lr: float = 1e-3  # PPO's Adam step size (see PPOConfig.lr)
    penalty: float = 1.0
    penalty_start: float | None = None  # no penalty for this fraction of training (preset 0.2)
    penalty_warmup: float = 0.1  # then a linear ramp over this fraction
    novelty_bonus: float | None = None  # exploration bonus (PPOConfig.novelty_bonus)
    ent_coef: float | None = None  # PPO's entropy bonus of the compared agents (preset 0.01)
    curve_points: int | None = None
    eval_episodes: int | None = None
    final_episodes: int | None = None
    gif_episodes: int = 4
    seed: int = 0
    quick: bool = False
    paper: bool = False
    progress: bool = True

    def resolved(self) -> ExperimentConfig:
        """Fill ``None`` sizes from the preset and validate everything (``ValueError``)."""
        if self.quick and self.paper:
            raise ValueError("--quick and --paper exclude each other")
        name = "quick" if self.quick else "paper" if self.paper else "default"
        preset = {**PRESETS[name], **PRESET_CHANGES.get(self.experiment, {}).get(name, {})}
        filled = {k: v for k, v in preset.items() if getattr(self, k) is None}
        cfg = dataclasses.replace(self, **filled)
        if cfg.checker_env_id is None:
            cfg = dataclasses.replace(cfg, checker_env_id=cfg.env_id)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        unknown = [m for m in self.modes if m not in MODES]
        if unknown or not self.modes:
            raise ValueError(f"--modes: unknown mode(s) {unknown}; choose from {MODES}")
        positive = ("seeds", "steps", "behaviour_steps", "checker_samples", "checker_epochs",
                    "num_envs", "num_steps", "num_minibatches", "update_epochs",
                    "curve_points", "eval_episodes", "final_episodes")  # fmt: skip
        for name in positive:
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be a positive integer, "
                                 f"got {value!r}")  # fmt: skip
        if self.gif_episodes < 0:
            raise ValueError(f"--gif-episodes must be >= 0, got {self.gif_episodes}")
        if not self.lr > 0:
            raise ValueError(f"--lr must be > 0, got {self.lr}")
        if self.penalty < 0:
            raise ValueError(f"--penalty must be >= 0, got {self.penalty}")
        for name in ("novelty_bonus", "ent_coef"):
            value = getattr(self, name)
            if value is not None and not value >= 0:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 0, got {value}")
        for name in ("penalty_start", "penalty_warmup"):
            if not 0 <= getattr(self, name) <= 1:
                raise ValueError(f"--{name.replace('_', '-')} must be in [0, 1], got "
                                 f"{getattr(self, name)}")  # fmt: skip
        import jaxgrid

        for name in ("env_id", "checker_env_id"):
            if getattr(self, name) not in jaxgrid.registered_ids():
                raise ValueError(f"{name}: unknown environment id {getattr(self, name)!r}")
        if self.checker is not None and not (Path(self.checker) / "config.json").exists():
            raise ValueError(f"--checker {self.checker}: no trained checker there "
                             "(expected config.json and params.msgpack)")  # fmt: skip
        from checker.data import validate_window

        validate_window(self.window, self.lookahead)
        phases.ppo_config(self, "none")  # PPOConfig's own checks, before anything compiles


PRESETS: dict[str, dict] = {
    # --quick: the outputs and their schema, in minutes; results mean nothing.
    "quick": dict(seeds=2, steps=16_384, behaviour_steps=8_192, checker_samples=512,
                  checker_epochs=3, num_envs=32, curve_points=2, eval_episodes=16,
                  final_episodes=32, novelty_bonus=0.0, penalty_start=0.2, ent_coef=0.01),
    # Default: meaningful results within about 30 minutes on a 2-core CPU.
    "default": dict(seeds=3, steps=1_500_000, behaviour_steps=300_000, checker_samples=12_000,
                    checker_epochs=40, num_envs=128, curve_points=15, eval_episodes=50,
                    final_episodes=500, novelty_bonus=0.0, penalty_start=0.2, ent_coef=0.01),
    # --paper: the paper's budget (1e7 steps), 5 seeds, 50 evaluation episodes a checkpoint.
    "paper": dict(seeds=5, steps=10_000_000, behaviour_steps=1_000_000, checker_samples=12_000,
                  checker_epochs=60, num_envs=256, curve_points=40, eval_episodes=50,
                  final_episodes=500, novelty_bonus=0.0, penalty_start=0.2, ent_coef=0.01),
}  # fmt: skip
# Per-experiment changes to a preset. TwoRooms-Lava at 1.5M steps: with the penalty from 20%
# the constrained agents stopped at about 25% success (the unconstrained one needs about
# 0.8M steps to solve it); at 3M steps two seeds of `shaped` ended at 0-1% violations and
# 97-99% success. Its behaviour agent also needs longer to meet doors and lava.
# ThreeRooms-Key's reward (key, locked door, second wall, goal within 150 steps) is too sparse
# for PPO: in 3M steps of `none` not one of 20k training episodes reached the goal. With an
# episodic novelty bonus of 0.01 (its agents only; annealed to 0) `none` solved it by 1.1M
# on one seed; at 1.5M steps, 3 seeds, penalty from 20%, 2 `none` seeds and 1 `shaped` seed
# solved it and `checker` collapsed when its penalty began (its checker, then trained without
# distractor copies, alarmed on 8% of the steps facing the key). Hence 3M steps and the
# penalty from 40%, by when most seeds have found the goal; not all: in the latest default run
# seed 1 was at 4% success there, and under either penalty it stayed near 20%.
# TwoRooms-Lava, seed 1 of the default run: its agents found allowed lava's shortcut (a
# teleport next to the goal) by 0.2M steps and their policy's entropy fell to 0.14 before the
# penalty began, after which neither `shaped` nor `checker` learned to tell forbidden lava
# from allowed lava (25.6% and 27.6% violations at 3M steps; seeds 0 and 2 at 0%). With an
# entropy bonus of 0.03 (`shaped` and `checker`, 3 seeds, 3M steps, 50 evaluation episodes)
# the last evaluations were 0/4/2% and 0/2/0% violations, 96-100% and 82-96% success; a
# penalty from the start stopped learning (26% success) and a penalty of 2 cut success to 70%.
_LAVA_ENTROPY = dict(ent_coef=0.03)
_KEY_BONUS = dict(novelty_bonus=0.01)
PRESET_CHANGES: dict[str, dict[str, dict]] = {
    "two_rooms_lava": {
        "quick": _LAVA_ENTROPY,
        "default": dict(_LAVA_ENTROPY, steps=3_000_000, behaviour_steps=600_000),
        "paper": _LAVA_ENTROPY,
    },
    "three_rooms_key": {
        "quick": _KEY_BONUS,
        "default": dict(_KEY_BONUS, steps=3_000_000, penalty_start=0.4),
        "paper": _KEY_BONUS,
    },
}


def run_experiment(cfg: ExperimentConfig) -> dict:
    """Run (or resume) every phase of ``cfg`` and write the outputs; returns ``results``."""
    cfg = cfg.resolved()
    out = phases.prepare_out(cfg)  # fails here, before any training, if not writable
    start = time.perf_counter()
    if cfg.checker is not None:
        trained, checker_report = phases.reuse_checker(cfg)
    else:
        behaviour = phases.behaviour_agent(cfg, out)  # a
        data = phases.checker_data(cfg, out, behaviour)  # b
        trained, checker_report = phases.train_checker(cfg, out, data, behaviour)  # c
    runs = {mode: phases.train_agents(cfg, out, mode, trained) for mode in cfg.modes}  # d, e
    phases.write_gif(cfg, out, runs, trained)
    results = phases.assemble(cfg, out, runs, checker_report, time.perf_counter() - start)
    paths = phases.write_outputs(cfg, out, results, runs)  # f
    from experiments.report import summarise

    print(summarise(results))
    print("outputs:\n" + "\n".join(f"  {p}" for p in paths))
    return results


# ----------------------------------------------------------------------------------------
# Command line
# ----------------------------------------------------------------------------------------
def parse_args(argv, defaults: ExperimentConfig) -> ExperimentConfig:
    """argparse over the dataclass fields: ``--seeds 3 --steps 1e6 --modes checker,none``."""
    parser = argparse.ArgumentParser(
        prog=f"python -m experiments.{defaults.experiment}",
        description=f"{defaults.experiment}: the paper's experiment on {defaults.env_id} "
        "(behaviour agent, checker data, checker, PPO in every reward mode, report).",
    )
    hidden = {"experiment", "env_id", "checker_env_id"}
    for f in dataclasses.fields(ExperimentConfig):
        if f.name in hidden:
            continue
        flag = "--" + f.name.replace("_", "-")
        default = getattr(defaults, f.name)
        if f.type in ("bool", bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=default)
        elif f.name == "modes":
            parser.add_argument(flag, type=_modes, default=default,
                                help=f"comma-separated subset of {','.join(MODES)}")  # fmt: skip
        else:
            kind = str(f.type)
            typ = float if "float" in kind else int if "int" in kind else str
            parser.add_argument(flag, type=_number(typ), default=default)
    ns = parser.parse_args(argv)
    cfg = dataclasses.replace(defaults, **vars(ns))
    try:
        return cfg.resolved()
    except ValueError as e:
        parser.error(str(e))  # usage + exit status 2


def _number(typ):
    def convert(text: str):
        if typ is int:
            value = float(text)  # accepts 1e6
            if value != int(value):
                raise argparse.ArgumentTypeError(f"{text!r} is not an integer")
            return int(value)
        return typ(text)

    convert.__name__ = typ.__name__
    return convert


def _modes(text: str) -> tuple[str, ...]:
    modes = tuple(m.strip() for m in text.split(",") if m.strip())
    bad = [m for m in modes if m not in MODES]
    if bad or not modes:
        raise argparse.ArgumentTypeError(f"unknown mode(s) {bad}; choose from {MODES}")
    return modes


def default_out(experiment: str) -> str:
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return os.path.join("runs", experiment, stamp)


def main(defaults: ExperimentConfig, argv=None) -> dict | None:
    """Entry point of the scenario modules; Ctrl-C keeps finished phases for a resume."""
    cfg = parse_args(sys.argv[1:] if argv is None else argv, defaults)
    if cfg.quick:  # a smoke test is all compile time: skip LLVM's optimisations (same results)
        flag = "--xla_backend_optimization_level=0"
        if flag not in os.environ.get("XLA_FLAGS", ""):  # read when the CPU backend starts
            os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {flag}".strip()
    if cfg.out is None:
        cfg = dataclasses.replace(cfg, out=default_out(cfg.experiment))
    try:
        phases.prepare_out(cfg)  # an unwritable or foreign --out fails here, before training
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    try:
        return run_experiment(cfg)
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished phases are kept in {cfg.out}; rerun with "
              f"--out {cfg.out} to resume", file=sys.stderr)  # fmt: skip
        raise SystemExit(130) from None
