"""The phases of :mod:`experiments.pipeline` around the checker, each resumable from its
artefact in ``--out``: the run directory and its configuration, the agents of every reward
mode (d, e) and the GIF.

Kept apart from the pipeline so that :func:`experiments.pipeline.run_experiment` reads as the
list of phases; the checker's phases (a-c, per kind of checker) are
:mod:`experiments.checker_phases`, which phase runs when, in which thread,
:mod:`experiments.scheduling`, and phase f (the results and their files)
:mod:`experiments.assembly`. Every phase returns what the next needs and, when its artefact
already exists, loads it instead of recomputing it. An artefact that is damaged (its
checksum, JSON or records fail) or was made from other inputs (the checker's report names
the checksums of its data and parameters, a PPO run the checker's) is made again by its
phase, with a message on stderr: safe, since every phase is deterministic given its
inputs."""

from __future__ import annotations

import dataclasses
import sys
import threading
from pathlib import Path
from typing import Protocol

import jax

from agents.checkpoint import ResumeError
from agents.config import RENAMED, PPOConfig, either_source
from agents.networks import start_memory
from agents.runner import run as run_ppo
from agents.train import make_learner
from checker.protocol import LABEL_LOOKAHEADS
from experiments import provenance
from jaxgrid.io import holds_declared_default, read_json, to_jsonable, write_json

__all__: list[str] = ["prepare_out", "ppo_config", "behaviour_config", "config_dict", "redo",
                      "resumed_run", "FREE_SETTINGS", "mode_arguments", "Precompiled",
                      "train_agents",
                      "write_gif"]  # fmt: skip


#: Settings that change no artefact: a run may resume, or be read back, with others.
FREE_SETTINGS = ("progress", "out", "modes", "machine_baseline", "workers")


def config_dict(cfg) -> dict:
    """``cfg`` as the JSON of ``config.json`` (nested configs as objects, tuples as lists)."""
    return to_jsonable(dataclasses.asdict(cfg))


def redo(phase: str, problem: Exception | str) -> None:
    """Say that ``phase`` is redone because its artefact is damaged; only where redoing it is
    safe: the phase is deterministic and everything after it checks what it was made from."""
    print(f"{phase}: {problem}\n{phase}: redoing this phase", file=sys.stderr)


def resumed_run(config: PPOConfig, checker=None, *, phase: str, **kwargs) -> dict:
    """:func:`agents.runner.run`, resumed; started over (with a message) when its saved state
    is damaged, missing a part, or was made with another checker."""
    try:
        return run_ppo(config, checker, desc=phase, **kwargs)
    except ResumeError as e:
        redo(phase, e)
        return run_ppo(config, checker, desc=phase, resume=False, **kwargs)


def _flat(d: dict, prefix: str = "") -> dict:
    """``{"ppo": {"lr": x}}`` -> ``{"ppo.lr": x}``."""
    out = {}
    for k, v in d.items():
        out.update(_flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
    return out


# ----------------------------------------------------------------------------------------
def prepare_out(cfg) -> Path:
    """Create ``cfg.out``, prove it writable and record the configuration.

    A directory that already holds ``config.json`` of another configuration is refused
    (mixing two runs' artefacts would be silently wrong); the same configuration resumes.
    The modes compared may differ: each mode's agents live in their own directory, which
    checks its own configuration, so a run can be extended by modes or reported on fewer.
    Settings that change no artefact (progress bars, the closing baseline timing, the
    number of workers) may differ.
    """
    out = Path(cfg.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".write-test"
        probe.write_text("ok")
        probe.unlink()
    except OSError as e:
        raise ValueError(f"--out {cfg.out}: not writable ({e.strerror or e})") from None
    mine = {k: v for k, v in _flat(config_dict(cfg)).items() if k not in FREE_SETTINGS}
    path = out / "config.json"
    if path.exists():
        try:
            saved = read_json(path)
        except ValueError as e:
            raise ValueError(
                f"{e}: it records the configuration of the run in --out "
                f"{cfg.out}; delete it to resume with these flags"
            ) from None
        theirs = {k: v for k, v in _flat(saved).items() if k not in FREE_SETTINGS}
        if "memory_checker.label" in theirs:  # recorded before it was named lookahead
            label = theirs.pop("memory_checker.label")
            theirs["memory_checker.lookahead"] = LABEL_LOOKAHEADS.get(label, label)
        for name, new in RENAMED.items():  # PPO settings recorded under an older name
            if f"ppo.{name}" in theirs:
                theirs[f"ppo.{new}"] = theirs.pop(f"ppo.{name}")
        diff = sorted(
            k for k in mine.keys() | theirs.keys()
            if mine.get(k) != theirs.get(k)
            and not (k not in theirs and holds_declared_default(cfg, k))
        )  # fmt: skip
        if diff:
            raise ValueError(
                f"--out {cfg.out} holds a run with another configuration (differs in "
                f"{', '.join(diff)}); pick a new --out or the same flags to resume it"
            )
    write_json(path, config_dict(cfg))
    provenance.record(out)  # which code made what this directory holds
    return out


def ppo_config(cfg, mode: str) -> PPOConfig:
    """The compared agents' :class:`PPOConfig` in reward mode ``mode``, with the experiment's
    ``constrained_cost`` as its ``cost_source`` where the mode can learn from either source."""
    source = cfg.constrained_cost if cfg.constrained_cost in either_source(mode) else None
    return _evaluated(cfg, dataclasses.replace(cfg.ppo, reward_mode=mode, cost_source=source))


def behaviour_config(cfg) -> PPOConfig:
    """The behaviour agent's: the compared agents' PPO in ``none`` mode on the checker's
    scenario, for ``behaviour_steps``."""
    ppo = cfg.ppo
    return _evaluated(cfg, dataclasses.replace(
        ppo, env_id=cfg.checker_env_id, reward_mode="none",
        total_timesteps=max(cfg.behaviour_steps, ppo.batch_size),
        recurrent=False,  # it only collects the checker's data, one action at a time
    ))  # fmt: skip


def _evaluated(cfg, ppo: PPOConfig) -> PPOConfig:
    """``ppo`` evaluated ``curve_points`` times: every ``max(1, updates // curve_points)``."""
    updates = ppo.total_timesteps // ppo.batch_size
    return dataclasses.replace(ppo, eval_every=max(1, updates // cfg.curve_points))


# ----------------------------------------------------------------------------------------
# d, e. PPO in every mode
# ----------------------------------------------------------------------------------------
def mode_arguments(cfg, mode: str, trained) -> tuple[PPOConfig, object, dict]:
    """The config, checker and common arguments of one mode's :func:`agents.runner.run`."""
    config = ppo_config(cfg, mode)
    checker = trained if config.uses_checker else None
    return config, checker, dict(seeds=tuple(range(cfg.seed, cfg.seed + cfg.seeds)),
                                 final_episodes=cfg.final_episodes,
                                 sweep=cfg.sweep_values or None)  # fmt: skip


class Precompiled(Protocol):
    """Where a mode's programs are compiled ahead (:class:`experiments.scheduling.Compiler`):
    :func:`train_agents` waits there for its mode's before it trains."""

    def wait(self, mode: str) -> None: ...


def train_agents(
    cfg, out: Path, mode: str, trained, compiler: Precompiled | None = None,
    cancel: threading.Event | None = None,
) -> dict:  # fmt: skip
    """``cfg.seeds`` agents of one reward mode, vmapped, checkpointed, finally evaluated
    (``cancel`` stops them at their next checkpoint, :func:`agents.runner.run`)."""
    if compiler is not None:
        compiler.wait(mode)
    config, checker, common = mode_arguments(cfg, mode, trained)
    result = resumed_run(config, checker, out_dir=out / "modes" / mode, progress=cfg.progress,
                      phase=f"d. {mode}", cancel=cancel, **common)  # fmt: skip
    result["config"] = config
    return result


def write_gif(cfg, out: Path, runs: dict, trained) -> Path | None:
    """A few evaluation episodes of the first seed's agent (checker mode when trained)."""
    if not cfg.gif_episodes:
        return None
    from jaxgrid.video import record_episodes

    mode = "checker" if "checker" in runs else next(iter(runs))
    config = runs[mode]["config"]
    learner = make_learner(config, trained if config.uses_checker else None)
    params = jax.tree.map(lambda x: x[0], runs[mode]["params"])
    batch = lambda obs: jax.tree.map(lambda x: x[None], obs)  # noqa: E731
    if config.recurrent:  # the memory lives here, reset where an episode starts
        step = jax.jit(lambda obs, key, m: learner.act(params, batch(obs), key, None, m))
        memory = [None]

        def policy(obs, state, key):
            if int(state.step_count) == 0:
                memory[0] = start_memory(learner.network, 1)
            action, memory[0] = step(obs, key, memory[0])
            return action[0]
    else:
        act = jax.jit(lambda obs, key: learner.act(params, batch(obs), key)[0])
        policy = lambda obs, state, key: act(obs, key)  # noqa: E731
    path = out / "episodes.gif"
    record_episodes(learner.env, policy, jax.random.PRNGKey(cfg.seed + 7), cfg.gif_episodes,
                    path)  # fmt: skip
    return path
