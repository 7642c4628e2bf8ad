"""Ablation: does labelling windows *just before* a violation cut violations during training?

Run ``python -m experiments.label_timing [--quick | --paper] [--out DIR]``.

The paper labels a window positive when a violation happens in the next step (``lookahead``
1, "just before") and hypothesises that this, rather than labelling the violating step itself
(``lookahead`` 0, "after"), is what lets checker-shaped reward prevent violations instead of
punishing them afterwards. This runs the TwoRooms pipeline in ``checker`` mode twice, once
per labelling, with everything else equal, and writes ``DIR/label_timing.json`` and
``DIR/label_timing.md``: checker metrics, violations during training and the final
evaluation of each. Flags are those of :mod:`experiments.two_rooms` (except ``--lookahead``
and ``--modes``); the blocked and lava counterfactuals and ``alarm_forward`` are off in both
arms, since they act only at lookahead 1 or charge the step after an alarm.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

from checker.train import CheckerTrainConfig
from experiments import stats
from experiments.pipeline import (
    ExperimentConfig,
    default_out,
    override,
    parse_args,
    run_experiment,
    scenario,
)
from jaxgrid.io import write_json

# Both arms without the options that exist only at lookahead 1 (the blocked and lava
# counterfactuals label a copy by the next step) or that charge the step after an alarm
# (after a violation, with "after" labels): otherwise the arms would differ in more than
# the labels' timing.
SCENARIO = override(scenario("label_timing", "TwoRooms-v0"), dict(
    modes=("checker",), ppo=dict(alarm_forward=False),
    checker_train=dict(blocked=0, lava_counterfactuals=False),
))  # fmt: skip
# The ablation sets these itself.
HIDDEN = {ExperimentConfig: {"modes": None}, CheckerTrainConfig: {"lookahead": None}}
LABELS = {1: "just before (lookahead 1)", 0: "after (lookahead 0)"}


def _iqm_cell(values, scale: float = 1.0, digits: int = 0) -> str:
    point, lo, hi = (scale * v for v in stats.bootstrap_ci(values))
    return f"{point:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _row(name: str, res: dict) -> str:
    m = res["methods"]["checker"]
    per_seed = m["final_per_seed"]
    return (
        f"| {name} | {res['checker']['test']['auroc']:.3f} | "
        f"{_iqm_cell(m['training_violations_per_seed'])} | "
        f"{_iqm_cell(m['training_violations_first20_per_seed'])} | "
        f"{_iqm_cell(per_seed['violation_rate'], 100.0, 1)} | "
        f"{_iqm_cell(per_seed['success_rate'], 100.0, 1)} | "
        f"{', '.join(str(int(v)) for v in m['training_violations_per_seed'])} |"
    )


def _comparison(results: dict, key: str) -> str:
    """P(just-before labels give fewer violations than "after" labels), with its interval."""
    before, after = (results[k]["methods"]["checker"][f"{key}_per_seed"] for k in (1, 0))
    p, lo, hi = stats.probability_of_improvement(before, after)
    return f"{p:.2f} [{lo:.2f}, {hi:.2f}]"


def main(argv=None) -> dict:
    cfg = parse_args(sys.argv[1:] if argv is None else argv, SCENARIO, hide=HIDDEN)
    out = Path(cfg.out or default_out(cfg.experiment))
    results = {}
    for k, name in LABELS.items():
        labels = dataclasses.replace(cfg.checker_train, lookahead=k)
        sub = dataclasses.replace(cfg, experiment=f"label_timing_lookahead{k}", modes=("checker",),
                                  checker_train=labels, out=str(out / f"lookahead{k}"))  # fmt: skip
        print(f"== checker trained with labels {name}")
        results[k] = run_experiment(sub)
    table = [
        "| labels | checker test AUROC | training violations | ... in the first 20% | "
        "final violation % | final success % | training violations per seed |",
        "|---|---:|---:|---:|---:|---:|---|",
    ] + [_row(LABELS[k], r) for k, r in results.items()]
    table += [
        "",
        "Interquartile mean over seeds [95% stratified-bootstrap interval]; training violations "
        "per seed, counted from the first update.",
        "",
        "P(just-before labels give fewer training violations than after labels): "
        f"{_comparison(results, 'training_violations')}; in the first 20% of training: "
        f"{_comparison(results, 'training_violations_first20')}.",
    ]
    summary = {
        str(k): {"checker": r["checker"], "checker_mode": r["methods"]["checker"]}
        for k, r in results.items()
    }
    write_json(out / "label_timing.json", summary)
    (out / "label_timing.md").write_text("# Label timing ablation\n\n" + "\n".join(table) + "\n")
    print("\n".join(table))
    print(f"outputs: {out / 'label_timing.md'}, {out / 'label_timing.json'}")
    return results


if __name__ == "__main__":
    main()
