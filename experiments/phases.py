"""The phases of :mod:`experiments.pipeline`, each resumable from its artefact in ``--out``.

Kept apart from the pipeline so that :func:`experiments.pipeline.run_experiment` reads as the
list of phases. Every phase returns what the next needs and, when its artefact already exists,
loads it instead of recomputing it. An artefact that is damaged (its checksum, JSON or records
fail) or was made from other inputs (the checker's report names the checksums of its data and
parameters, a PPO run the checker's) is made again by its phase, with a message on stderr:
safe, since every phase is deterministic given its inputs.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import threading
from concurrent.futures import FIRST_EXCEPTION, ThreadPoolExecutor, wait
from pathlib import Path

import jax
import numpy as np

import checker as chk
import jaxgrid
from agents.config import PPOConfig
from agents.networks import start_memory
from agents.runner import ResumeError, precompile
from agents.runner import run as run_ppo
from agents.train import make_learner
from checker.protocol import LABEL_LOOKAHEADS
from checker.store import params_sha256
from experiments import provenance, stats
from jaxgrid.io import holds_declared_default, read_json, to_jsonable, write_json, write_jsonl

# Checker metrics copied into results.json (all rates).
CHECKER_KEYS = ("accuracy", "precision", "recall", "f1", "auroc", "ece")
HELDOUT_FRACTION = 4  # held-out / transfer sets are checker_samples // 4 windows


def _config_dict(cfg) -> dict:
    """``cfg`` as the JSON of ``config.json`` (nested configs as objects, tuples as lists)."""
    return to_jsonable(dataclasses.asdict(cfg))


def _redo(phase: str, problem: Exception | str) -> None:
    """Say that ``phase`` is redone because its artefact is damaged; only where redoing it is
    safe: the phase is deterministic and everything after it checks what it was made from."""
    print(f"{phase}: {problem}\n{phase}: redoing this phase", file=sys.stderr)


def _run_ppo(config: PPOConfig, checker=None, *, phase: str, **kwargs) -> dict:
    """:func:`agents.runner.run`, resumed; started over (with a message) when its saved state
    is damaged, missing a part, or was made with another checker."""
    try:
        return run_ppo(config, checker, desc=phase, **kwargs)
    except ResumeError as e:
        _redo(phase, e)
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
    mine = {k: v for k, v in _flat(_config_dict(cfg)).items() if k not in free}
    path = out / "config.json"
    if path.exists():
        try:
            saved = read_json(path)
        except ValueError as e:
            raise ValueError(f"{e}: it records the configuration of the run in --out "
                             f"{cfg.out}; delete it to resume with these flags") from None
        theirs = {k: v for k, v in _flat(saved).items() if k not in free}
        if "memory_checker.label" in theirs:  # recorded before it was named lookahead
            label = theirs.pop("memory_checker.label")
            theirs["memory_checker.lookahead"] = LABEL_LOOKAHEADS.get(label, label)
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
    write_json(path, _config_dict(cfg))
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
            _redo("b. checker data", e)
    key = jax.random.fold_in(jax.random.PRNGKey(cfg.seed), 1)
    data = _collect(cfg, cfg.checker_env_id, behaviour, key, cfg.checker_samples)
    data.save(path)
    print(f"b. checker data: {len(data)} windows, natural positive rate "
          f"{data.meta['natural_positive_rate']:.4f}")  # fmt: skip
    return data


def _rates(metrics: dict) -> dict:
    """The six metrics of results.json; undefined ones (no predicted positives, one class)
    become 0 for precision/F1 (the usual zero-division convention) and 0.5 for AUROC."""
    fill = {"auroc": 0.5}
    return {k: float(metrics[k]) if metrics[k] is not None else fill.get(k, 0.0)
            for k in CHECKER_KEYS}  # fmt: skip


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
            _redo("c. checker", e)
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
    report = {split: _rates(m) for split, m in details.items()}
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
    return _rates(metrics)


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
def _agents(cfg, mode: str, trained) -> tuple[PPOConfig, object, dict]:
    """The config, checker and common arguments of one mode's :func:`agents.runner.run`."""
    config = ppo_config(cfg, mode)
    checker = trained if config.uses_checker else None
    return config, checker, dict(seeds=tuple(range(cfg.seed, cfg.seed + cfg.seeds)),
                                 final_episodes=cfg.final_episodes,
                                 sweep=cfg.sweep_values or None)  # fmt: skip


def train_agents(
    cfg, out: Path, mode: str, trained, compiler: Compiler | None = None,
    cancel: threading.Event | None = None,
) -> dict:  # fmt: skip
    """``cfg.seeds`` agents of one reward mode, vmapped, checkpointed, finally evaluated
    (``cancel`` stops them at their next checkpoint, :func:`agents.runner.run`)."""
    if compiler is not None:
        compiler.wait(mode)
    config, checker, common = _agents(cfg, mode, trained)
    result = _run_ppo(config, checker, out_dir=out / "modes" / mode, progress=cfg.progress,
                      phase=f"d. {mode}", cancel=cancel, **common)  # fmt: skip
    result["config"] = config
    return result


# Seconds per update of each mode relative to ``none`` (TwoRooms, benchmarks.train_speed):
# modes are compiled and started slowest first, so that the last to finish is a short one.
TRAINING_COST = {"shield": 1.9, "checker": 1.2, "lagrangian": 1.15, "shaped": 1.0,
                 "none": 1.0, "shield_monitor": 0.97}  # fmt: skip


class Workers:
    """Runs the phases that train, ``n`` at once, in threads.

    Each phase is its own compiled program, and XLA releases the GIL while one runs. The
    kernels of both run on XLA's CPU thread pool, which one PPO program leaves idle part of
    the time (many small, dependent kernels): on 2 cores two reward modes trained at once
    finished 1.2x (TwoRooms) to 1.4x (HazardRooms) sooner than one after the other, with
    bit-identical results (``python -m benchmarks.threads``, ``docs/decisions.md``); three
    at once gained less. ``n`` 1 runs them one after the other. :meth:`close` sets
    :attr:`cancel`, which every run checks before each chunk.
    """

    def __init__(self, n: int):
        self.cancel = threading.Event()
        self.pool = ThreadPoolExecutor(n, thread_name_prefix="train")

    def submit(self, fn, *args, **kwargs):
        """``fn(*args, **kwargs)`` in a free thread: a ``concurrent.futures.Future``."""
        return self.pool.submit(fn, *args, **kwargs)

    @staticmethod
    def results(jobs: dict) -> dict:
        """``{name: future}`` -> ``{name: result}``; the first failure is raised as soon as
        it happens, not when its turn comes."""
        done, _ = wait(jobs.values(), return_when=FIRST_EXCEPTION)
        for job in done:
            if not job.cancelled() and job.exception() is not None:
                raise job.exception()
        return {name: job.result() for name, job in jobs.items()}

    def close(self, wait: bool = True) -> None:
        """Stop the threads at their next chunk; ``wait`` for them (Ctrl-C does not: a
        command then leaves at once through :func:`jaxgrid.rundir.exit_now`, which waits
        only for a checkpoint being written)."""
        self.cancel.set()
        self.pool.shutdown(wait=wait, cancel_futures=True)


class Compiler:
    """Compiles the agents' programs in one background thread while the main thread works.

    XLA's compiler releases the GIL, so the modes' programs compile on the second core while
    the first trains the behaviour agent, the checker or another mode: ``--quick`` is mostly
    compile time. :meth:`submit` queues the modes without a checker (before it is trained)
    or those with one; :meth:`wait` before a mode trains: it waits for that mode's programs,
    or takes the job back if the thread has not started it (the run then compiles them).
    A mode whose run directory holds its last checkpoint gets only its final evaluation
    compiled: resuming a finished run retrains nothing.
    """

    def __init__(self, cfg):
        self.cfg, self.jobs = cfg, {}
        self.order: list[str] = []  # the modes in the order they were queued
        self.pool = ThreadPoolExecutor(1, thread_name_prefix="compile")

    def submit(self, checkers: dict | None = None) -> None:
        """Queue the modes that need no checker (``checkers`` None) or those that need one,
        each with its checker in ``checkers`` ({mode: trained checker}), the slowest to
        train first (:data:`TRAINING_COST`)."""
        for mode in sorted(self.cfg.modes, key=lambda m: -TRAINING_COST.get(m, 1.0)):
            config, checker, common = _agents(self.cfg, mode, (checkers or {}).get(mode))
            if mode not in self.jobs and config.uses_checker == (checkers is not None):
                out_dir = Path(self.cfg.out) / "modes" / mode  # finished: the final only
                self.jobs[mode] = self.pool.submit(precompile, config, checker, **common,
                                                   out_dir=out_dir)  # fmt: skip
                self.order.append(mode)

    def wait(self, mode: str) -> None:
        job = self.jobs.pop(mode, None)
        if job is not None and not job.cancel():
            job.result()

    def close(self) -> None:
        self.pool.shutdown(wait=False, cancel_futures=True)


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


# ----------------------------------------------------------------------------------------
# f. results
# ----------------------------------------------------------------------------------------
def _method(result: dict, final_episodes: int) -> dict:
    steps, ev, final = result["steps"], result["eval"], result["final"]
    curve = [
        {"step": int(s), **{k: float(np.mean(ev[k][:, i])) for k in ev}}
        for i, s in enumerate(steps)
    ]
    keys = ("violation_rate", "mean_reward", "success_rate")
    seeds = len(result["seeds"])
    violations = result["train_violations"]
    early = result.get("train_violations_early", np.zeros_like(violations))
    entry = {
        "final": {**{k: float(np.mean(final[k])) for k in keys},
                  "episodes": int(final_episodes * seeds)},
        "training_violations": int(np.rint(np.mean(violations))),
        "training_violations_per_seed": [int(v) for v in violations],
        "training_violations_first20": int(np.rint(np.mean(early))),
        "training_violations_first20_per_seed": [int(v) for v in early],
        "training_alarms_per_seed": [int(v) for v in result["train_alarms"]],
        "curve": curve,
        "seeds": seeds,
        "final_per_seed": {k: [float(v) for v in final[k]] for k in keys},
        "curve_per_seed": {"step": [int(s) for s in steps],
                           **{k: np.asarray(ev[k]).tolist() for k in keys}},
        "wall_s": float(result["wall_s"]),
    }  # fmt: skip
    per_seed = {**entry["final_per_seed"], "training_violations": violations,
                "training_violations_first20": early}  # fmt: skip
    if "unshielded" in final:  # a shield mode: its policy alone, too
        off = final["unshielded"]
        entry["final_unshielded"] = {**{k: float(np.mean(off[k])) for k in keys},
                                     "episodes": int(final_episodes * seeds)}  # fmt: skip
        entry["final_unshielded_per_seed"] = {k: [float(v) for v in off[k]] for k in keys}
        per_seed.update({f"unshielded_{k}": off[k] for k in keys})
    entry["iqm"] = {k: stats.summary(v) for k, v in per_seed.items()}
    return entry


def _comparisons(methods: dict) -> dict:
    """P(a run of X has fewer training violations than a run of Y), for X in checker and
    shield against Y = shaped (the paper's claim and the shield's), where both ran."""
    out = {}
    for x in ("checker", "shield"):
        if x not in methods or "shaped" not in methods:
            continue
        for key in ("training_violations", "training_violations_first20"):
            p, lo, hi = stats.probability_of_improvement(
                methods[x][f"{key}_per_seed"], methods["shaped"][f"{key}_per_seed"])
            out[f"{x}_beats_shaped_{key}"] = {"p": p, "lo": lo, "hi": hi}
    return out


def _memory_extras(checker_report: dict) -> dict:
    """A memory checker's test AUROC per constraint type, on late budget violations and on
    counting itself (``auroc_by``); nothing for a window checker."""
    test = (checker_report.get("details") or {}).get("test") or {}
    if "per_type" not in test:
        return {}
    by = {t: v["auroc"] for t, v in test["per_type"].items()}
    by.update(late_budget=test["late_budget"]["auroc"],
              costly_budget=test["costly_budget"]["auroc"])  # fmt: skip
    return {"auroc_by": by}


def _shield_checker(report: dict | None) -> dict:
    """The shield's own checker (``ExperimentConfig.shield_guided``): its test metrics, the
    share of oracle actions in its streams and its AUROC by type; nothing without one."""
    if report is None:
        return {}
    return {"shield": {"test": report["test"], "guided": report["training"]["guided"],
                       **_memory_extras(report)}}  # fmt: skip


def assemble(cfg, out: Path, runs: dict, checker_report: dict, total_s: float) -> dict:
    """The ``results.json`` object (schema: :data:`experiments.report.RESULTS_SCHEMA`)."""
    methods = {mode: _method(r, cfg.final_episodes) for mode, r in runs.items()}
    return {
        "experiment": cfg.experiment,
        "config": {**_config_dict(cfg), "penalty_start": cfg.ppo.penalty_start},
        "checker": {
            "test": checker_report["test"],
            "heldout": checker_report.get("heldout"),
            "transfer": checker_report.get("transfer"),
            "trained_on": cfg.checker_env_id,
            "kind": cfg.checker_kind,
            **_memory_extras(checker_report),
            **_shield_checker(checker_report.get("shield")),
        },
        "methods": methods,
        "comparisons": _comparisons(methods),
        "code": read_json(out / "code.json") if (out / "code.json").exists() else [],
        "timing": {"total_s": float(total_s),
                   "modes_s": {m: float(r["wall_s"]) for m, r in runs.items()},
                   "devices": [str(d) for d in jax.devices()], "cpu_count": os.cpu_count()},
    }  # fmt: skip


def write_outputs(cfg, out: Path, results: dict, runs: dict) -> list[Path]:
    """results.json/.md, curves.png and metrics.jsonl (every mode's records, tagged)."""
    from experiments.report import curves_from_results, plot_curves, write_report

    paths = list(write_report(results, out))
    title = f"{cfg.experiment} ({cfg.env_id}, {cfg.seeds} seeds)"
    paths.append(plot_curves(curves_from_results(results), out / "curves.png", title))
    write_jsonl(out / "metrics.jsonl", ({"mode": mode, **rec} for mode, r in runs.items()
                                        for rec in r["records"]))  # fmt: skip
    paths += [out / "metrics.jsonl", out / "config.json", out / "checker.json"]
    if (out / "episodes.gif").exists():
        paths.append(out / "episodes.gif")
    return [p for p in paths if Path(p).exists()]


__all__: list[str] = ["prepare_out", "ppo_config", "behaviour_config",
                      "behaviour_agent", "checker_data", "train_checker", "reuse_checker",
                      "train_agents", "write_gif", "assemble", "write_outputs",
                      "select_agents", "write_sweep", "sweep_table"]  # fmt: skip


# ----------------------------------------------------------------------------------------
# f'. a sweep: results per swept value, and a summary across values
# ----------------------------------------------------------------------------------------
def select_agents(result: dict, name: str, value: float) -> dict:
    """The part of a swept run's result (:func:`agents.runner.run`) whose agents ran with
    ``name = value``: the same keys, as if those agents had been a run of their own."""
    idx = np.flatnonzero(np.asarray(result["sweep"][name]) == value)
    take = lambda x: np.asarray(x)[idx]  # noqa: E731
    out = {k: v for k, v in result.items() if k not in ("runner", "sweep")}
    out["eval"] = {k: take(v) for k, v in result["eval"].items()}
    for k in ("train_violations", "train_violations_early", "train_alarms"):
        out[k] = take(result[k])
    out["seeds"] = [result["seeds"][i] for i in idx]
    out["params"] = jax.tree.map(lambda a: a[idx], result["params"])
    if "final" in result:
        out["final"] = jax.tree.map(take, result["final"])
    out["records"] = [r for r in result["records"] if r[name] == value]
    return out


def write_sweep(cfg, out: Path, runs: dict, checker_report: dict, total_s: float) -> dict:
    """Per swept value, the usual outputs in ``out/<name>=<value>/``; across values,
    ``sweep.json``, ``sweep.md`` and ``sweep.png`` (IQM final violations and success per
    value and mode) and the training throughput of each mode's one program."""
    from experiments.report import plot_sweep  # lazy: matplotlib

    ((name, values),) = cfg.sweep_values.items()
    rows, paths = [], []
    for value in values:
        sub_out = out / f"{name}={value:g}"
        sub_out.mkdir(parents=True, exist_ok=True)
        sub_cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, **{name: value}),
                                      sweep=None, out=str(sub_out))  # fmt: skip
        sub_runs = {mode: select_agents(r, name, value) for mode, r in runs.items()}
        results = assemble(sub_cfg, sub_out, sub_runs, checker_report, total_s)
        results["sweep"] = {name: value}
        paths += write_outputs(sub_cfg, sub_out, results, sub_runs)
        for mode, m in results["methods"].items():
            rows.append({name: value, "mode": mode, **{k: m["iqm"][k] for k in (
                "violation_rate", "success_rate", "training_violations")}})  # fmt: skip
    agents = len(values) * cfg.seeds
    steps = {m: int(r["steps"][-1]) * agents for m, r in runs.items()}
    throughput = {m: {"agents": agents, "steps_per_s": steps[m] / r["wall_s"],
                      "steps_per_s_per_agent": steps[m] / r["wall_s"] / agents,
                      "wall_s": float(r["wall_s"])} for m, r in runs.items()}  # fmt: skip
    summary = {"experiment": cfg.experiment, "sweep": {"name": name, "values": list(values)},
               "seeds": cfg.seeds, "rows": rows, "throughput": throughput,
               "total_s": float(total_s)}  # fmt: skip
    write_json(out / "sweep.json", summary)
    table = sweep_table(summary)
    (out / "sweep.md").write_text(table)
    plot_sweep(summary, out / "sweep.png", f"{cfg.experiment} ({cfg.env_id}): {name} sweep")
    paths += [out / "sweep.json", out / "sweep.md", out / "sweep.png"]
    print(table)
    print("outputs:\n" + "\n".join(f"  {p}" for p in paths if Path(p).exists()))
    return summary


def sweep_table(summary: dict) -> str:
    """Markdown: one row per (value, mode), IQM [95% interval]; then each mode's throughput."""
    name = summary["sweep"]["name"]

    def cell(s, scale, digits):
        return f"{scale * s['iqm']:.{digits}f} [{scale * s['lo']:.{digits}f}, " \
               f"{scale * s['hi']:.{digits}f}]"

    lines = [f"# Sweep of {name}: {summary['experiment']}", "",
             f"| {name} | mode | final violation % | success % | training violations |",
             "|---:|---|---:|---:|---:|"]  # fmt: skip
    for r in summary["rows"]:
        lines.append(f"| {r[name]:g} | {r['mode']} | {cell(r['violation_rate'], 100, 1)} | "
                     f"{cell(r['success_rate'], 100, 1)} | "
                     f"{cell(r['training_violations'], 1, 0)} |")  # fmt: skip
    lines += ["", f"Interquartile mean over {summary['seeds']} seeds per value [95% stratified-"
              "bootstrap interval]. Every mode trains all its agents (values x seeds) in one "
              "compiled program:", "",
              "| mode | agents | env steps/s, all agents | per agent | wall time |",
              "|---|---:|---:|---:|---:|"]  # fmt: skip
    for mode, t in summary["throughput"].items():
        lines.append(f"| {mode} | {t['agents']} | {t['steps_per_s']:,.0f} | "
                     f"{t['steps_per_s_per_agent']:,.0f} | {t['wall_s']:.0f} s |")
    lines.append("\nThroughput counts compilation and evaluations in the wall time.")
    return "\n".join(lines) + "\n"
