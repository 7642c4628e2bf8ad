"""Ablation: does labelling windows *just before* a violation cut violations during training?

Run ``python -m experiments.label_timing [--quick | --paper] [--out DIR]``.

The paper labels a window positive when a violation happens in the next step (``lookahead``
1, "just before") and hypothesises that this, rather than labelling the violating step itself
(``lookahead`` 0, "after"), is what lets checker-shaped reward prevent violations instead of
punishing them afterwards. This runs the TwoRooms pipeline in ``checker`` mode twice, once
per labelling, with everything else equal, and writes ``DIR/label_timing.json`` and
``DIR/label_timing.md``: checker metrics, violations during training and the final
evaluation of each. Flags are those of :mod:`experiments.two_rooms` (except ``--lookahead``,
``--modes`` and ``--checker``: each arm trains its own checker, with its labels); the blocked
and lava counterfactuals and ``alarm_forward`` are off in both arms, since they act only at
lookahead 1 or charge the step after an alarm.

As the other experiments: ``--out`` is locked for the run (:func:`jaxgrid.rundir.lock`), both
arms' directories (``DIR/lookahead1``, ``DIR/lookahead0``) are checked before either trains,
and Ctrl-C keeps the finished phases, which a rerun with the same flags resumes.
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

from checker import cli
from experiments import phases, stats
from experiments.pipeline import default_out, parse_args, resume_command, run_experiment
from experiments.presets import EXPERIMENTS
from jaxgrid import rundir
from jaxgrid.io import write_json

SCENARIO = EXPERIMENTS["label_timing"]  # both arms; their differences are in the row
PROG = "python -m experiments.label_timing"
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
    """Run both arms of the ablation with ``argv`` (default ``sys.argv[1:]``) and write the
    report; returns each arm's results, by lookahead.

    Bad flags exit with status 2 before anything compiles; ``--checker`` is refused
    (``ValueError``), and so, before either arm trains, is an ``--out`` that cannot be written
    or that holds a run of other flags; a second process on it gets
    :class:`~jaxgrid.rundir.LockHeld`. Ctrl-C exits with status 130 and says how to resume.
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    if any(a == "--checker" or a.startswith("--checker=") for a in argv):
        raise ValueError(
            "--checker: label_timing trains one checker per labelling (lookahead "
            "1 and 0) and compares them; a trained checker has one labelling"
        )
    cfg = parse_args(argv, SCENARIO)
    out = Path(cfg.out or default_out(cfg.experiment))
    arms = {}
    for k in LABELS:
        labels = dataclasses.replace(cfg.checker_train, lookahead=k)
        arms[k] = dataclasses.replace(cfg, experiment=f"label_timing_lookahead{k}",
                                      modes=("checker",), checker_train=labels,
                                      out=str(out / f"lookahead{k}"))  # fmt: skip
    try:
        with rundir.lock(out, PROG, resume_command("label_timing", argv, str(out))):
            for sub in arms.values():  # both arms' directories, before either trains
                phases.prepare_out(sub)
            return _run(out, arms)
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished phases are kept in {out}; resume with\n  "
              f"{resume_command('label_timing', argv, str(out))}", file=sys.stderr)  # fmt: skip
        raise SystemExit(130) from None


def _run(out: Path, arms: dict) -> dict:
    results = {}
    for k, sub in arms.items():
        print(f"== checker trained with labels {LABELS[k]}")
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
    cli.run_main(main, PROG)
