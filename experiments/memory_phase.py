"""Phases a-c for constraints that count: the memory checker (:mod:`checker.memory_model`).

A window of a few frames cannot tell the third step on lava from the first, so scenarios whose
sentences have budgets or triggers (``HazardRooms-v0``) train a recurrent checker instead of a
behaviour agent, windows and a window checker:

* **data**: whole streams of the agents' own env (its sentences, auto-reset) under the random
  behaviour policy :data:`checker.data.BEHAVIOUR` (a share of the actions from the BFS
  oracle with ``guided``), labelled by the ground-truth monitor: by default one step ahead
  (the step out of each frame violates), with ``lookahead=0`` the step into each frame
  (:func:`checker.data.relabel`);
* **checker**: :func:`checker.train.train_memory_checker`, saved in ``DIR/checker/``;
* **the shield's own checker** (``ExperimentConfig.shield_guided``): the same, with another
  share of oracle actions, in ``DIR/shield_checker/`` and ``DIR/shield_checker.json``;
* **report**: on fresh streams of the same env (another key), the metrics of the window
  checker's report at the agents' ``checker_threshold``, and AUROC per constraint type, on
  late budget violations and on counting itself (``details.test``), in ``DIR/checker.json``.

Like every phase it is skipped when its artefacts are there and match (the report names the
parameters' checksum), and redone with a message when they are damaged.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np

import checker as chk
from checker import memory_model
from checker.data import collect_streams, relabel
from checker.metrics import binary_metrics, evaluate_streams, predict_streams
from checker.store import params_sha256
from checker.train import fit_memory_checker
from experiments.phases import redo
from experiments.report import checker_rates
from jaxgrid.io import read_json, write_json

SHIELD_CHECKER = "shield_checker"  # the shield's own checker: DIR/shield_checker{/,.json}


def train_memory_checker(cfg, out: Path, name: str = "checker", guided: float | None = None):
    """``(trained, report)``: the memory checker of ``cfg`` (trained, or loaded from ``out``),
    in ``out/<name>/`` with its report ``out/<name>.json``; ``guided`` replaces
    ``cfg.memory_checker.guided`` (the shield's own checker, ``ExperimentConfig.shield_guided``).
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
