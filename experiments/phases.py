"""The phases of :mod:`experiments.pipeline`, each resumable from its artefact in ``--out``.

Kept apart from the pipeline so that :func:`experiments.pipeline.run_experiment` reads as the
list of phases; which phase runs when, in which thread, is :mod:`experiments.scheduling`, and
phase f (the results and their files) is :mod:`experiments.assembly`. Every phase returns what
the next needs and, when its artefact already exists, loads it instead of recomputing it. An
artefact that is damaged (its checksum, JSON or records fail) or was made from other inputs
(the checker's report names the checksums of its data and parameters, a PPO run the
checker's) is made again by its phase, with a message on stderr: safe, since every phase is
deterministic given its inputs."""

from __future__ import annotations

import dataclasses
import sys
import threading
from pathlib import Path
from typing import Protocol

import jax

import checker as chk
import jaxgrid
from agents.checkpoint import ResumeError
from agents.config import RENAMED, PPOConfig
from agents.networks import start_memory
from agents.runner import run as run_ppo
from agents.train import make_learner
from checker.protocol import LABEL_LOOKAHEADS
from checker.store import params_sha256
from experiments import provenance
from experiments.report import checker_rates
from jaxgrid.io import holds_declared_default, read_json, to_jsonable, write_json

HELDOUT_FRACTION = 4  # held-out / transfer sets are checker_samples // 4 windows


__all__: list[str] = ["prepare_out", "ppo_config", "behaviour_config", "config_dict", "redo",
                      "AgentPolicy", "behaviour_agent", "checker_data", "train_checker",
                      "load_reused", "reuse_checker", "mode_arguments", "Precompiled",
                      "train_agents", "write_gif"]  # fmt: skip


def config_dict(cfg) -> dict:
    """``cfg`` as the JSON of ``config.json`` (nested configs as objects, tuples as lists)."""
    return to_jsonable(dataclasses.asdict(cfg))


def redo(phase: str, problem: Exception | str) -> None:
    """Say that ``phase`` is redone because its artefact is damaged; only where redoing it is
    safe: the phase is deterministic and everything after it checks what it was made from."""
    print(f"{phase}: {problem}\n{phase}: redoing this phase", file=sys.stderr)


def _run_ppo(config: PPOConfig, checker=None, *, phase: str, **kwargs) -> dict:
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
    free = ("progress", "out", "modes", "machine_baseline", "workers")
    mine = {k: v for k, v in _flat(config_dict(cfg)).items() if k not in free}
    path = out / "config.json"
    if path.exists():
        try:
            saved = read_json(path)
        except ValueError as e:
            raise ValueError(
                f"{e}: it records the configuration of the run in --out "
                f"{cfg.out}; delete it to resume with these flags"
            ) from None
        theirs = {k: v for k, v in _flat(saved).items() if k not in free}
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
    """The compared agents' :class:`PPOConfig` in reward mode ``mode``."""
    return _evaluated(cfg, dataclasses.replace(cfg.ppo, reward_mode=mode))


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
# a. behaviour agent
# ----------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class AgentPolicy:
    """A trained agent as a :func:`checker.collect` policy (hashable: a static argument);
    with ``epsilon`` > 0 each action is uniformly random with that probability."""

    config: PPOConfig
    epsilon: float = 0.0

    def __call__(self, params, obs, state, key):
        del state
        if not self.epsilon:
            return make_learner(self.config).act(params, obs, key)
        key, k_explore, k_random = jax.random.split(key, 3)
        action = make_learner(self.config).act(params, obs, key)
        return chk.with_random_actions(action, k_explore, k_random, self.epsilon)


def behaviour_agent(cfg, out: Path, cancel: threading.Event | None = None):
    """PPO in ``none`` mode on the checker's scenario for ``behaviour_steps`` (resumable;
    ``cancel`` stops it at its next checkpoint, :func:`agents.runner.run`)."""
    config = behaviour_config(cfg)
    result = _run_ppo(config, seeds=(cfg.seed,), out_dir=out / "behaviour",
                      progress=cfg.progress, phase="a. behaviour agent",
                      cancel=cancel)  # fmt: skip
    params = jax.tree.map(lambda x: x[0], result["params"])
    ev = {k: float(v[0, -1]) for k, v in result["eval"].items()}
    print(f"a. behaviour agent ({config.total_timesteps} steps): success "
          f"{ev['success_rate']:.2f}, violations {ev['violation_rate']:.2f}")  # fmt: skip
    return AgentPolicy(config), params


# ----------------------------------------------------------------------------------------
# b. checker data, c. checker
# ----------------------------------------------------------------------------------------
def _collect(cfg, env_id: str, behaviour, key, samples: int, split: str = "train"):
    """Windows of ``behaviour`` (``(AgentPolicy, params)``) on ``env_id``; the noisy oracle
    plays instead when there is no agent or it was trained on another scenario."""
    if behaviour is None or env_id != behaviour[0].config.env_id:
        policy, params = chk.noisy_oracle_policy, chk.NoisyOracleParams(salt=cfg.seed)
    else:
        policy, params = behaviour
        policy = dataclasses.replace(policy, epsilon=float(cfg.collect_epsilon))
    settings = cfg.checker_train
    return chk.collect(jaxgrid.make(env_id, split=split), policy, params, key, samples,
                       settings.window, settings.lookahead, env_id=env_id,
                       max_steps=cfg.collect_max_steps,
                       final_windows=settings.final_windows)  # fmt: skip


def _small_samples(cfg) -> int:
    """Windows of the held-out and transfer sets."""
    return max(64, cfg.checker_samples // HELDOUT_FRACTION)


def checker_data(cfg, out: Path, behaviour):
    """Balanced, auto-labelled windows of the behaviour agent's rollouts (resumable)."""
    path = out / "checker_data"
    if path.with_suffix(".npz").exists() or path.with_suffix(".json").exists():
        try:
            return chk.CheckerDataset.load(path)
        except (ValueError, FileNotFoundError) as e:  # damaged, or one of the two files lost
            redo("b. checker data", e)
    key = jax.random.fold_in(jax.random.PRNGKey(cfg.seed), 1)
    data = _collect(cfg, cfg.checker_env_id, behaviour, key, cfg.checker_samples)
    data.save(path)
    print(f"b. checker data: {len(data)} windows, natural positive rate "
          f"{data.meta['natural_positive_rate']:.4f}")  # fmt: skip
    return data


def train_checker(cfg, out: Path, data, behaviour):
    """Train the checker as ``python -m checker`` does (:func:`checker.train_checker`, which
    splits off the test set), then measure it on test, held-out language and transfer sets."""
    ckpt, report_path = out / "checker", out / "checker.json"
    data_sha256 = read_json(out / "checker_data.json").get("npz_sha256")
    if ckpt.exists() or report_path.exists():
        try:
            trained, report = chk.load(ckpt), read_json(report_path)
            if report.get("params_sha256") != params_sha256(ckpt):
                raise ValueError(f"{report_path} describes other parameters than {ckpt}")
            if report.get("data_sha256") != data_sha256:
                raise ValueError(f"{ckpt} was trained on other data than {out}/checker_data")
            return trained, report
        except (ValueError, FileNotFoundError) as e:
            redo("c. checker", e)
    trained, history, test = chk.train_checker(data, cfg.checker_train, progress=cfg.progress)
    chk.save(trained, ckpt)
    key = jax.random.fold_in(jax.random.PRNGKey(cfg.seed), 2)
    held = _collect(cfg, cfg.checker_env_id, behaviour, key, _small_samples(cfg), "heldout")
    details = {"test": chk.evaluate(trained, test), "heldout": chk.evaluate(trained, held)}
    report = _checker_report(details, history)
    report["transfer"] = _transfer(cfg, trained, report)
    report.update(params_sha256=params_sha256(ckpt), data_sha256=data_sha256)
    write_json(ckpt / "report.json", report)  # travels with the checker for --checker reuse
    write_json(report_path, report)  # last: its presence marks the phase as done
    print(f"c. checker: test AUROC {report['test']['auroc']:.3f} F1 {report['test']['f1']:.3f}"
          f", held-out AUROC {report['heldout']['auroc']:.3f}")  # fmt: skip
    return trained, report


def _checker_report(details: dict, history: dict | None) -> dict:
    report = {split: checker_rates(m) for split, m in details.items()}
    report["details"] = details
    if history is not None:
        report["training"] = {k: history.get(k) for k in ("epochs_run", "best_epoch",
                                                          "best_val_loss")}  # fmt: skip
    return report


def _transfer(cfg, trained, report: dict) -> dict | None:
    """The checker on the experiment's own scenario when it was trained on another one."""
    if cfg.env_id == trained.env_id or not trained.env_id:
        return report.get("transfer")
    key = jax.random.fold_in(jax.random.PRNGKey(cfg.seed), 3)
    # The behaviour agent knows another scenario: the noisy oracle plays this one.
    data = _collect(cfg, cfg.env_id, None, key, _small_samples(cfg))
    metrics = chk.evaluate(trained, data)
    report.setdefault("details", {})[f"transfer_{cfg.env_id}"] = metrics
    print(f"c. checker ({trained.env_id}) on {cfg.env_id}: AUROC {metrics['auroc']}")
    return checker_rates(metrics)


def load_reused(cfg):
    """``--checker DIR`` loaded and checked against ``cfg`` before anything is written or
    compiled: a checker whose kind, window, label timing (``--lookahead`` / ``--memory-lookahead``),
    inputs (``--checker-actions``) or view size differ from the experiment's is refused by
    name, since its alarms would mean something else (its vocabulary and sentence length are
    checked by :func:`checker.load`). Returns the trained checker."""
    path = Path(cfg.checker)
    trained = chk.load(path)
    kind, flag = trained.kind, f"--checker {path}"
    if kind != cfg.checker_kind:
        raise ValueError(f"{flag}: a {kind} checker, and {cfg.experiment} trains its agents "
                         f"with a {cfg.checker_kind} checker")  # fmt: skip
    view = cfg.ppo.make_env().view_size
    if trained.config.view_size != view:
        raise ValueError(f"{flag}: trained on {trained.config.view_size}x"
                         f"{trained.config.view_size} views, and {cfg.env_id} shows {view}x"
                         f"{view}")  # fmt: skip
    if kind == "window":
        mismatch = [("window", trained.config.window, cfg.checker_train.window, "--window"),
                    ("lookahead", trained.lookahead, cfg.checker_train.lookahead,
                     "--lookahead")]  # fmt: skip
    else:
        mismatch = [("lookahead", trained.lookahead, cfg.memory_checker.lookahead,
                     "--memory-lookahead"),
                    ("actions", trained.config.actions, cfg.checker_actions,
                     "--checker-actions")]  # fmt: skip
    for name, theirs, mine, option in mismatch:
        if theirs != mine:
            raise ValueError(f"{flag}: trained with {name} {theirs!r}, and this run asks for "
                             f"{option} {mine!r}; pass {option} {theirs!r} to use it, or omit "
                             "--checker to train one")  # fmt: skip
    return trained


def reuse_checker(cfg, trained):
    """``--checker DIR`` (``trained``, from :func:`load_reused`) and its report
    (``report.json`` of a pipeline run, or ``metrics.json`` of ``python -m checker``), which
    must name the parameters' checksum: a report of other parameters is refused."""
    path = Path(cfg.checker)
    digest = params_sha256(path)
    found = [path / name for name in ("report.json", "metrics.json") if (path / name).exists()]
    if not found:
        raise ValueError(f"--checker {path}: neither report.json nor metrics.json found, so "
                         "its test metrics are unknown")  # fmt: skip
    mine = [p for p in found if digest is not None
            and read_json(p).get("params_sha256") == digest]  # fmt: skip
    if not mine:
        raise ValueError(
            f"--checker {path}: {' and '.join(p.name for p in found)} describe(s) other "
            f"parameters than {path / 'params.msgpack'} (or predate checksums); retrain it "
            f"with `python -m checker --out {path} --overwrite`"
        )
    if mine[0].name == "report.json":
        report = read_json(mine[0])
    else:
        m = read_json(mine[0])["metrics"]
        details = {"test": m["test"]}
        if m.get("heldout_language"):
            details["heldout"] = m["heldout_language"]
        report = _checker_report(details, None)
        report.setdefault("heldout", None)
    report = dict(report, transfer=_transfer(cfg, trained, dict(report)))
    write_json(Path(cfg.out) / "checker.json", dict(report, reused_from=str(path)))
    return trained, report


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
    result = _run_ppo(config, checker, out_dir=out / "modes" / mode, progress=cfg.progress,
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
