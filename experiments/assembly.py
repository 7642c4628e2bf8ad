"""Phase f: an experiment's runs put together into its results and output files.

- :func:`assemble`: the ``results.json`` object of the modes' runs and the checker's report
  (schema: :data:`experiments.report.RESULTS_SCHEMA`), with the IQM summaries and the
  probabilities of improvement of :mod:`experiments.stats`;
- :func:`write_outputs`: ``results.json``, ``results.md``, ``curves.png``, ``metrics.jsonl``;
- :func:`select_agents` and :func:`write_sweep`: a swept run (``--sweep``) split into the
  results of each swept value, and a summary across values.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import jax
import numpy as np

from experiments import stats
from experiments.phases import config_dict
from experiments.report import (
    COST_KEYS,
    curves_from_results,
    plot_curves,
    plot_sweep,
    sweep_table,
    write_report,
)
from jaxgrid.io import read_json, write_json, write_jsonl

__all__ = ["assemble", "select_agents", "write_outputs", "write_sweep"]


def _pooled(values, key: str) -> float:
    """Seeds' evaluations pooled: the mean of their means, the maximum of their maxima."""
    return float(np.max(values) if key == "max_costly_run" else np.mean(values))


def _method(result: dict, final_episodes: int) -> dict:
    steps, ev, final = result["steps"], result["eval"], result["final"]
    curve = [
        {"step": int(s), **{k: float(np.mean(ev[k][:, i])) for k in ev}}
        for i, s in enumerate(steps)
    ]
    rates = ("violation_rate", "mean_reward", "success_rate")
    keys = rates + tuple(k for k in COST_KEYS if k in final)
    curve_keys = rates + tuple(k for k in COST_KEYS if k in ev)
    seeds = len(result["seeds"])
    violations = result["train_violations"]
    early = result.get("train_violations_early", np.zeros_like(violations))
    entry = {
        "final": {**{k: _pooled(final[k], k) for k in keys},
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
                           **{k: np.asarray(ev[k]).tolist() for k in curve_keys}},
        "wall_s": float(result["wall_s"]),
    }  # fmt: skip
    per_seed = {**entry["final_per_seed"], "training_violations": violations,
                "training_violations_first20": early}  # fmt: skip
    if "train_cost_rate" in result:  # OmniSafe's cost rate: training cost over training steps
        history = np.asarray(result["train_cost_rate"])
        entry["training_cost_rate"] = float(np.mean(history[:, -1]))
        entry["training_cost_rate_per_seed"] = [float(v) for v in history[:, -1]]
        entry["training_cost_per_seed"] = [float(v) for v in result["train_env_cost"]]
        entry["curve_per_seed"]["training_cost_rate"] = history.tolist()
        per_seed["training_cost_rate"] = history[:, -1]
    if "unshielded" in final:  # a shield mode: its policy alone, too
        off = final["unshielded"]
        entry["final_unshielded"] = {**{k: _pooled(off[k], k) for k in keys},
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
                methods[x][f"{key}_per_seed"], methods["shaped"][f"{key}_per_seed"]
            )
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
        "config": {**config_dict(cfg), "penalty_start": cfg.ppo.penalty_start},
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
    paths = list(write_report(results, out))
    title = f"{cfg.experiment} ({cfg.env_id}, {cfg.seeds} seeds)"
    paths.append(plot_curves(curves_from_results(results), out / "curves.png", title))
    write_jsonl(out / "metrics.jsonl", ({"mode": mode, **rec} for mode, r in runs.items()
                                        for rec in r["records"]))  # fmt: skip
    paths += [out / "metrics.jsonl", out / "config.json", out / "checker.json"]
    if (out / "episodes.gif").exists():
        paths.append(out / "episodes.gif")
    return [p for p in paths if Path(p).exists()]


def select_agents(result: dict, name: str, value: float) -> dict:
    """The part of a swept run's result (:func:`agents.runner.run`) whose agents ran with
    ``name = value``: the same keys, as if those agents had been a run of their own."""
    idx = np.flatnonzero(np.asarray(result["sweep"][name]) == value)
    take = lambda x: np.asarray(x)[idx]  # noqa: E731
    out = {k: v for k, v in result.items() if k not in ("runner", "sweep")}
    out["eval"] = {k: take(v) for k, v in result["eval"].items()}
    for k in ("train_violations", "train_violations_early", "train_alarms"):
        out[k] = take(result[k])
    for k in ("train_env_cost", "train_cost_rate"):  # absent for runs older than them
        if k in result:
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
