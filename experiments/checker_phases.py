"""Phases a-c of :mod:`experiments.pipeline`: the checker, for every kind of checker.

:data:`CHECKER_PHASES` declares, per kind (``ExperimentConfig.checker_kind``), how its
phases run, what a reused checker (``--checker``) must share with the run, which settings
the kind reads and which it refuses; the pipeline looks the kind up and never branches on
it. The window checker (the paper's) is made from a behaviour agent (a), windows of its
rollouts (b) and supervised training (c); the memory checker, for sentences that count,
from random-policy streams of the agents' own env (:func:`memory_checker`). Like every
phase (:mod:`experiments.phases`) each is skipped when its artefact is there and matches,
and redone with a message when it is damaged or was made from other inputs."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

import checker as chk
import jaxgrid
from agents.config import PPOConfig
from agents.train import make_learner
from checker import memory_model
from checker.data import collect_streams, relabel
from checker.metrics import binary_metrics, evaluate_streams, predict_streams
from checker.store import params_sha256
from checker.train import fit_memory_checker
from experiments.phases import behaviour_config, redo, resumed_run
from experiments.report import checker_rates
from jaxgrid.io import read_json, write_json

HELDOUT_FRACTION = 4  # held-out / transfer sets are checker_samples // 4 windows

__all__: list[str] = ["AgentPolicy", "behaviour_agent", "checker_data", "train_checker",
                      "load_reused", "reuse_checker", "SHIELD_CHECKER", "memory_checker",
                      "CheckerPhases", "CHECKER_PHASES"]  # fmt: skip


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
    result = resumed_run(config, seeds=(cfg.seed,), out_dir=out / "behaviour",
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
    compiled: a checker whose kind, view size or any setting its kind declares
    (:attr:`CheckerPhases.matches`: window and label timing, or label timing and inputs)
    differ from the experiment's is refused by name, since its alarms would mean something
    else (its vocabulary and sentence length are checked by :func:`checker.load`). Returns
    the trained checker."""
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
    for name, theirs, mine, option in CHECKER_PHASES[kind].matches(cfg, trained):
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
# a-c of a memory checker: streams, the recurrent checker, its report
# ----------------------------------------------------------------------------------------
SHIELD_CHECKER = "shield_checker"  # the shield's own checker: DIR/shield_checker{/,.json}


def memory_checker(cfg, out: Path, name: str = "checker", guided: float | None = None):
    """``(trained, report)``: the memory checker of ``cfg`` (trained, or loaded from ``out``),
    in ``out/<name>/`` with its report ``out/<name>.json``; ``guided`` replaces
    ``cfg.memory_checker.guided`` (the shield's own checker, ``ExperimentConfig.shield_guided``).

    A window of frames cannot tell the third step on lava from the first, so sentences with
    budgets or triggers train a recurrent checker on whole streams of the agents' own env
    under the random behaviour policy (a share of oracle actions with ``guided``), labelled
    by the monitor ``lookahead`` steps ahead; its report measures it on fresh streams (AUROC
    per constraint type, on late budget violations and on counting, ``details.test``).
    """
    ckpt, report_path = out / name, out / f"{name}.json"
    phase = "c. memory checker" if name == "checker" else f"c'. {name.replace('_', ' ')}"
    settings = cfg.memory_checker
    if guided is not None:
        settings = dataclasses.replace(settings, guided=guided)
    if ckpt.exists() or report_path.exists():
        try:
            trained, report = chk.load(ckpt), read_json(report_path)
            if trained.kind != "memory":
                raise ValueError(f"{ckpt} holds a window checker, not a memory checker")
            if report.get("params_sha256") != params_sha256(ckpt):
                raise ValueError(f"{report_path} describes other parameters than {ckpt}")
            made = report.get("training", {}).get("guided")
            if made != settings.guided:  # a resume with another --memory-guided
                raise ValueError(f"{ckpt} was trained with guided {made}, not {settings.guided}")
            if trained.config.actions != cfg.checker_actions:  # another --checker-actions
                raise ValueError(f"{ckpt} reads actions: {trained.config.actions}, and "
                                 f"--checker-actions is {cfg.checker_actions}")  # fmt: skip
            return trained, report
        except (ValueError, FileNotFoundError) as e:
            redo(phase, e)
    env = cfg.ppo.make_env()
    key = jax.random.PRNGKey(cfg.seed)
    data = collect_streams(env, key, settings.streams, settings.steps, settings.guided)
    data = relabel(data, settings.lookahead)
    config = memory_model.MemoryCheckerConfig(view_size=env.view_size, actions=cfg.checker_actions)
    params, losses = fit_memory_checker(data, config, settings, phase if cfg.progress else None)
    threshold = cfg.ppo.checker_threshold
    trained = memory_model.TrainedMemoryChecker(params=params, config=config, env_id=cfg.env_id,
                                                threshold=threshold,
                                                lookahead=settings.lookahead)  # fmt: skip
    chk.save(trained, ckpt)
    test = collect_streams(env, jax.random.fold_in(key, 1), settings.streams, settings.steps,
                           settings.guided)  # fmt: skip
    test = relabel(test, settings.lookahead)
    probs = predict_streams(params, config, test)
    valid = test["valid"]
    metrics = {**binary_metrics(test["label"][valid], probs[valid], threshold),
               **evaluate_streams(probs, test, lookahead=settings.lookahead)}  # fmt: skip
    report = {
        "kind": "memory",
        "test": checker_rates(metrics),  # undefined rates filled as the window checker's are
        "heldout": None,  # the agents' sentences are a fixed list: no held-out templates
        "transfer": None,
        "details": {"test": metrics},
        "training": {"updates": settings.updates, "streams": settings.streams,
                     "steps": settings.steps, "lookahead": settings.lookahead,
                     "guided": settings.guided, "actions": config.actions,
                     "train_positives": int(data["label"].sum()),
                     "final_loss": float(np.mean(losses[-50:]))},
        "params_sha256": params_sha256(ckpt),
    }  # fmt: skip
    write_json(ckpt / "report.json", report)  # travels with the checker for --checker reuse
    write_json(report_path, report)  # last: its presence marks the phase as done
    types = ", ".join(f"{t} {v['auroc']:.3f}" for t, v in metrics["per_type"].items()
                      if v["auroc"] is not None)  # fmt: skip
    print(f"{phase}: test AUROC {report['test']['auroc']:.3f} ({types}); counting "
          f"(costly budget) {metrics['costly_budget']['auroc']}")  # fmt: skip
    return trained, report


# ----------------------------------------------------------------------------------------
# The checker's phases of each kind
# ----------------------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class CheckerPhases:
    """How an experiment makes a checker of one kind: the pipeline looks its kind up here
    and never asks which kind it is.

    ``make(cfg, out, keep, cancel) -> (trained, report)`` runs the kind's phases (``keep``
    receives what they made for the caller, ``cancel`` stops a training at its next
    checkpoint); ``matches(cfg, trained)`` lists ``(name, theirs, mine, flag)`` of what a
    reused checker (``--checker``) must share with the run; ``check(cfg)`` refuses settings
    the kind cannot run with (``ValueError``); ``settings`` names the
    :class:`~experiments.pipeline.ExperimentConfig` parts only this kind reads (hidden from
    the command line of the other kinds' experiments); ``steps`` names the phases (``--help``).
    """

    make: Callable
    matches: Callable
    check: Callable
    settings: tuple[str, ...]
    steps: str


def _window_phases(cfg, out: Path, keep: dict, cancel: threading.Event | None):
    behaviour = keep["behaviour"] = behaviour_agent(cfg, out, cancel)  # a
    data = keep["data"] = checker_data(cfg, out, behaviour)  # b
    return train_checker(cfg, out, data, behaviour)  # c


def _window_matches(cfg, trained) -> list[tuple]:
    return [
        ("window", trained.config.window, cfg.checker_train.window, "--window"),
        ("lookahead", trained.lookahead, cfg.checker_train.lookahead, "--lookahead"),
    ]


def _window_check(cfg) -> None:
    me = type(cfg).__name__
    if cfg.shield_guided is not None:
        raise ValueError(f"{me}.shield_guided: the shield's own checker is a memory checker, "
                         f"and {cfg.experiment} trains a window checker")  # fmt: skip
    if cfg.checker_actions:
        raise ValueError(f"{me}.checker_actions: only a memory checker reads actions, and "
                         f"{cfg.experiment} trains a window checker")  # fmt: skip
    settings, rows = cfg.checker_train, cfg.checker_train.training_rows(cfg.checker_samples)
    if cfg.checker is None and rows < settings.batch_size:
        raise ValueError(
            f"{me}.checker_samples {cfg.checker_samples} leaves {rows} windows to train on "
            f"after CheckerTrainConfig.test_fraction and CheckerTrainConfig.val_fraction, "
            f"fewer than CheckerTrainConfig.batch_size {settings.batch_size}"
        )


def _memory_phases(cfg, out: Path, keep: dict, cancel: threading.Event | None):
    del keep, cancel  # no behaviour agent, no windows: one training, seconds to minutes
    return memory_checker(cfg, out)


def _memory_matches(cfg, trained) -> list[tuple]:
    return [
        ("lookahead", trained.lookahead, cfg.memory_checker.lookahead, "--memory-lookahead"),
        ("actions", trained.config.actions, cfg.checker_actions, "--checker-actions"),
    ]


#: Every kind of checker an experiment can train (``ExperimentConfig.checker_kind``).
CHECKER_PHASES: dict[str, CheckerPhases] = {
    "window": CheckerPhases(
        make=_window_phases, matches=_window_matches, check=_window_check,
        settings=("behaviour_steps", "checker_samples", "collect_max_steps",
                  "collect_epsilon", "checker_train"),
        steps="behaviour agent, checker data, checker"),
    "memory": CheckerPhases(
        make=_memory_phases, matches=_memory_matches, check=lambda cfg: None,
        settings=("memory_checker", "shield_guided", "checker_actions"),
        steps="random-policy streams, memory checker"),
}  # fmt: skip
