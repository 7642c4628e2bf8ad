"""The Markdown report and the console summary of an experiment's results.

- :func:`results_table`: the methods, their comparisons and the checker's metrics as
  Markdown tables.
- :func:`write_report`: ``results.json`` and ``results.md``, validated first
  (:func:`experiments.report.schema.validate_results`), each written atomically.
- :func:`summarise`: the end-of-run console summary.
- :func:`sweep_table`: a sweep's summary (:func:`experiments.assembly.write_sweep`) as
  Markdown.
- :func:`benchmark_table`: the benchmark's summary (:mod:`experiments.benchmark`) as one
  Markdown table, a row per level and method.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import NamedTuple

import numpy as np

from agents.config import either_source
from experiments.report.schema import (
    CHECKER_METRICS,
    CHECKER_SPLITS,
    COST_KEYS,
    MODE_LABELS,
    ordered_modes,
    validate_results,
)
from experiments.stats import mean_ci
from jaxgrid.io import atomic_write, write_json

__all__ = ["BENCHMARK_COLUMNS", "ReportPaths", "benchmark_table", "results_table", "summarise",
           "sweep_table", "write_report"]  # fmt: skip

#: The benchmark table's columns: ``(key of a method's iqm summaries, header, scale)``.
BENCHMARK_COLUMNS: tuple[tuple[str, str, float], ...] = (
    ("violation_rate", "Final violation %", 100.0),
    ("success_rate", "Success %", 100.0),
    ("mean_reward", "Return", 1.0),
    ("mean_cost", "Episode cost", 1.0),
    ("training_violations", "Training violations", 1.0),
    ("mean_costly_run", "Longest costly run", 1.0),
)


def _cell(entry: Mapping, key: str, scale: float, digits: int, final: str = "final") -> str:
    """``IQM [lo, hi]`` (95% bootstrap) from the entry's ``iqm`` summaries when present, else
    ``mean ± t half-width`` from ``final_per_seed`` (>= 2 seeds), else the pooled final."""
    name = key if final == "final" else f"unshielded_{key}"
    summary = (entry.get("iqm") or {}).get(name)
    if summary is not None:
        point, lo, hi = (summary[k] * scale for k in ("iqm", "lo", "hi"))
        return f"{point:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"
    per_seed = (entry.get(f"{final}_per_seed") or {}).get(key)
    if per_seed is not None and len(per_seed) >= 2:
        mean, lo, hi = mean_ci(np.asarray(per_seed, dtype=np.float64) * scale)
        return f"{mean:.{digits}f} ± {(hi - lo) / 2:.{digits}f}"
    return f"{float(entry[final][key]) * scale:.{digits}f}"


def _count(entry: Mapping, key: str, digits: int = 0) -> str:
    """A training figure of the entry (``entry[key]``): ``IQM [lo, hi]`` where ``iqm`` has it,
    else its value, else ``n/a``."""
    summary = (entry.get("iqm") or {}).get(key)
    if summary is not None:
        point, lo, hi = (summary[k] for k in ("iqm", "lo", "hi"))
        return f"{point:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"
    if key not in entry:
        return "n/a"
    return str(entry[key]) if digits == 0 else f"{float(entry[key]):.{digits}f}"


def _finals(entry: Mapping) -> list[tuple[str, str]]:
    """The evaluations of a mode's rows: as deployed, and for a shield mode its policy alone."""
    off = [("final_unshielded", ", shield off")] if "final_unshielded" in entry else []
    return [("final", ""), *off]


def _costs_table(methods: Mapping) -> list[str]:
    """The cost metrics' rows (:data:`COST_KEYS` and the training cost rate); none for results
    written before they existed."""
    if not any(k in e["final"] for e in methods.values() for k in COST_KEYS):
        return []
    lines = ["", "| Method | Episode cost | Longest costly run | ... its maximum "
             "| Training cost rate |", "|---|---:|---:|---:|---:|"]  # fmt: skip
    for mode in ordered_modes(methods):
        e = methods[mode]
        for final, note in _finals(e):
            cells = [_cell(e, k, 1.0, digits, final) if k in e[final] else "n/a"
                     for k, digits in zip(COST_KEYS, (3, 2, 1), strict=True)]  # fmt: skip
            cells.append(_count(e, "training_cost_rate", 4))
            lines.append(f"| {mode} ({MODE_LABELS.get(mode, mode)}{note}) | "
                         + " | ".join(cells) + " |")  # fmt: skip
    return lines + [
        "",
        "Final evaluation: the episode cost (the env's cost summed over an episode) and the "
        "longest run of consecutive costly steps of an episode, averaged over episodes, and its "
        "maximum over them; training cost rate: the env cost of every training step over "
        "their number, from the first update (OmniSafe's). Interquartile mean over seeds [95% "
        "stratified-bootstrap interval].",
    ]


def results_table(results: Mapping) -> str:
    """Markdown tables: one row per mode (shield modes twice: as deployed, and the policy
    without its shield), the comparisons, then the checker metrics per split.

    Method columns: final violation %, mean reward, success % and training violations (all,
    and in the first 20% of training): the interquartile mean over seeds with its 95%
    stratified-bootstrap interval where ``iqm`` summaries exist, else the mean; seeds, final
    evaluation episodes. Where the results hold them, a second table gives the cost metrics
    (:data:`~experiments.report.schema.COST_KEYS`, the training cost rate) the same way.
    Checker rows: test, heldout, transfer (``n/a`` when null).
    """
    lines = [
        "| Method | Final violation % | Mean reward | Success % | Training violations "
        "| ... in the first 20% | Seeds | Eval episodes |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    methods = results["methods"]
    for mode in ordered_modes(methods):
        e = methods[mode]
        for final, note in _finals(e):
            lines.append(
                f"| {mode} ({MODE_LABELS.get(mode, mode)}{note}) "
                f"| {_cell(e, 'violation_rate', 100.0, 1, final)} "
                f"| {_cell(e, 'mean_reward', 1.0, 3, final)} "
                f"| {_cell(e, 'success_rate', 100.0, 1, final)} "
                f"| {_count(e, 'training_violations')} "
                f"| {_count(e, 'training_violations_first20')} "
                f"| {int(e['seeds'])} "
                f"| {int(e[final]['episodes'])} |"
            )
    lines += [
        "",
        "Interquartile mean over seeds [95% stratified-bootstrap interval]; training "
        "violations per seed, counted from the first update.",
    ]
    lines += _costs_table(methods)
    comparisons = results.get("comparisons") or {}
    if comparisons:
        lines += ["", "| Comparison | P | 95% interval |", "|---|---:|---:|"]
        for name, c in comparisons.items():
            x, key = name.split("_beats_shaped_")
            what = "in the first 20% of training" if key.endswith("first20") else "in training"
            lines.append(f"| P({x} has fewer violations than shaped {what}) "
                         f"| {c['p']:.2f} | [{c['lo']:.2f}, {c['hi']:.2f}] |")  # fmt: skip
    lines += [
        "",
        "| Checker split | Accuracy | Precision | Recall | F1 | AUROC | ECE |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    chk = results.get("checker") or {}

    def row(name: str, m: Mapping) -> str:
        return f"| {name} |" + "".join(f" {float(m[k]):.3f} |" for k in CHECKER_METRICS)

    for split in CHECKER_SPLITS:
        m = chk.get(split)
        if m is None:
            if split == "transfer":
                continue  # only shown by experiments that measure transfer
            lines.append(f"| {split} |" + " n/a |" * len(CHECKER_METRICS))
            continue
        lines.append(row(split, m))
    shield = chk.get("shield")
    if shield:  # the shield's own checker, on its own streams' test split
        lines.append(row(f"test, shield's checker (guided {float(shield['guided']):g})",
                         shield["test"]))  # fmt: skip
    by = chk.get("auroc_by")
    if by:  # a memory checker: how well it ranks each constraint type, and counts
        rows = [("memory checker", by)]
        if shield and shield.get("auroc_by"):
            rows.append(("shield's checker", shield["auroc_by"]))
        lines += ["", "| Checker AUROC on test | " + " | ".join(by) + " |",
                  "|---|" + "---:|" * len(by)]  # fmt: skip
        lines += [f"| {name} | " + " | ".join("n/a" if aurocs.get(k) is None else
                                              f"{aurocs[k]:.3f}" for k in by) + " |"
                  for name, aurocs in rows]  # fmt: skip
    return "\n".join(lines) + "\n"


class ReportPaths(NamedTuple):
    """Files written by :func:`write_report`."""

    json: Path
    md: Path


def _format_duration(seconds: float) -> str:
    s = int(round(seconds))
    h, rem = divmod(s, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h {m:02d}m {s:02d}s" if h else f"{m}m {s:02d}s"


def _baseline_note(timing: Mapping) -> str:
    """`` on a machine where ...``: the baseline learner's figure, when it was measured."""
    base = timing.get("machine_baseline")
    if not base:
        return ""
    return (
        f", on a machine where the PureJaxRL-style PPO baseline (`python -m "
        f"benchmarks.purejaxrl_ppo --env {base['env']}`) runs at {float(base['sps']):,.0f} "
        f"steps/s ({base['device']})"
    )


def _code_note(entries: list) -> str:
    """Which code made the results (``results["code"]``, :mod:`experiments.provenance`)."""
    if not entries:
        return ""
    last = entries[-1]
    git = f", git {last['git']}" if last.get("git") else ""
    jax_version = last["versions"].get("jax")
    note = f"\nCode: sources sha256 {last['sha256'][:12]}{git}, jax {jax_version}.\n"
    if len(entries) > 1:
        note += (
            f"\n**Warning: {len(entries)} versions of the code wrote into this directory** (a "
            "resume after a change; `code.json`): phases made by an earlier one were kept, so "
            "a fresh run of the same command may give other figures.\n"
        )
    return note


def _smoke_note(results: Mapping) -> str:
    """A warning atop a ``--quick`` run's report: its sizes test the outputs, not the agents."""
    if not (results.get("config") or {}).get("quick"):
        return ""
    return ("**A `--quick` smoke test: these numbers mean nothing** (a few thousand steps, "
            "two seeds); run without `--quick` for results.\n\n")  # fmt: skip


def write_report(results: dict, out_dir: str | os.PathLike) -> ReportPaths:
    """Validate ``results`` then atomically write ``results.json`` and ``results.md``.

    Raises ``ValueError`` (see :func:`validate_results`) before touching the filesystem when
    ``results`` is invalid. Numpy values are converted, NaN/inf extras become null
    (:func:`jaxgrid.io.write_json`). Each file is written atomically, so a reader never sees a
    partial file. Returns ``ReportPaths(json, md)``.
    """
    validate_results(results)
    out = Path(out_dir)
    md = (
        f"# Results: {results['experiment']}\n\n"
        + _smoke_note(results)
        + results_table(results)
        + f"\nTotal wall time: {_format_duration(float(results['timing']['total_s']))}"
        + _baseline_note(results["timing"])
        + ".\n"
        + _code_note(results.get("code") or [])
    )
    json_path, md_path = out / "results.json", out / "results.md"
    write_json(json_path, results)
    atomic_write(md_path, md)
    return ReportPaths(json_path, md_path)


def summarise(results: Mapping) -> str:
    """Short multi-line console summary: one line per mode, the checker AUROC and wall time."""
    quick = (results.get("config") or {}).get("quick")
    lines = [f"{results.get('experiment', '?')}" + (" (--quick: these numbers mean nothing)"
                                                    if quick else "") + ":"]  # fmt: skip
    methods = results["methods"]
    width = max(len(m) for m in methods)
    for mode in ordered_modes(methods):
        e = methods[mode]
        lines.append(
            f"  {mode:<{width}}  violations {_cell(e, 'violation_rate', 100.0, 1)}%"
            f"  reward {_cell(e, 'mean_reward', 1.0, 3)}"
            f"  success {_cell(e, 'success_rate', 100.0, 1)}%"
            + (f"  cost {_cell(e, 'mean_cost', 1.0, 3)}" if "mean_cost" in e["final"] else "")
            + f"  training violations {_count(e, 'training_violations')}"
            f"  ({int(e['seeds'])} seeds, {int(e['final']['episodes'])} episodes)"
        )
    chk = results.get("checker") or {}
    parts = [
        f"{split} {float(chk[split]['auroc']):.3f}"
        for split in CHECKER_SPLITS
        if chk.get(split) is not None
    ]
    if chk.get("shield") is not None:
        parts.append(f"shield's checker {float(chk['shield']['test']['auroc']):.3f}")
    lines.append("  checker AUROC: " + (", ".join(parts) if parts else "n/a"))
    total = (results.get("timing") or {}).get("total_s")
    if total is not None:
        lines.append(f"  total time: {_format_duration(float(total))}")
    return "\n".join(lines)


def sweep_table(summary: dict) -> str:
    """Markdown: one row per (value, mode), IQM [95% interval]; then each mode's throughput."""
    name = summary["sweep"]["name"]

    def cell(s, scale, digits):
        return (
            f"{scale * s['iqm']:.{digits}f} [{scale * s['lo']:.{digits}f}, "
            f"{scale * s['hi']:.{digits}f}]"
        )

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
        lines.append(
            f"| {mode} | {t['agents']} | {t['steps_per_s']:,.0f} | "
            f"{t['steps_per_s_per_agent']:,.0f} | {t['wall_s']:.0f} s |"
        )
    lines.append("\nThroughput counts compilation and evaluations in the wall time.")
    return "\n".join(lines) + "\n"


def benchmark_table(summary: Mapping) -> str:
    """The benchmark's ``summary`` (``OUT/benchmark.json``) as Markdown: a row per level and
    method, IQM [95% bootstrap interval] over seeds in each :data:`BENCHMARK_COLUMNS` column
    (``n/a`` where the level's results hold no such figure), and the levels ``pending``."""
    columns = BENCHMARK_COLUMNS
    lines = ["| Level | Method | " + " | ".join(h for _, h, _ in columns) + " |",
             "|---|---|" + "---:|" * len(columns)]  # fmt: skip
    for level, entry in summary["levels"].items():
        for method, figures in entry["methods"].items():
            cells = []
            for key, _, scale in columns:
                f = figures.get(key)
                digits = 0 if key == "training_violations" else 1 if scale == 100 else 2
                cells.append("n/a" if f is None else
                             f"{f['iqm'] * scale:.{digits}f} [{f['lo'] * scale:.{digits}f}, "
                             f"{f['hi'] * scale:.{digits}f}]")  # fmt: skip
            lines.append(f"| {level} | {method} | " + " | ".join(cells) + " |")
    config = summary.get("config", {})
    lines += ["", f"Interquartile mean over {config.get('seeds')} seeds [95% stratified-"
              "bootstrap interval]; per-seed values in benchmark.json."]  # fmt: skip
    # Only the modes that can learn from either source depend on the setting; name them.
    methods = dict.fromkeys(m for entry in summary["levels"].values() for m in entry["methods"])
    switched = [m for m in methods if either_source(m)]
    if switched:
        monitor = config.get("constrained_cost") == "monitor"
        source = "the monitor's ground-truth cost" if monitor else "the checker's alarms"
        lines[-1] += f" {', '.join(switched)} learn from {source}."
    pending = summary.get("pending") or []
    if pending:
        lines += ["", f"**Not yet run: {', '.join(pending)}** (the same command resumes)."]
    return "\n".join(lines) + "\n"
