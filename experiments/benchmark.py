"""Every method on every benchmark level, one table: ``python -m experiments.benchmark``.

Each level is a row of :data:`experiments.presets.EXPERIMENTS` (named by
:data:`experiments.presets.BENCHMARK_LEVELS`), run by the one pipeline
(:func:`experiments.pipeline.run_experiment`) with the methods asked for as its reward
modes, in ``OUT/<level>/``; so every phase of every level resumes where it stopped after an
interruption, however often, and a finished level is only read back. After every level,
``OUT/benchmark.md`` holds one table (IQM [95% bootstrap interval] over seeds of each
method's final violations, success, return, episode cost, training violations and longest
costly run, per level), ``OUT/benchmark.json`` the same figures with their per-seed values,
and ``OUT/<level>.png`` one picture per level (success against training violations, a point
per method with its intervals), of the levels done so far, the others named as pending.

::

    python -m experiments.benchmark [--quick] [--levels two_rooms,...] [--methods none,...]
        [--seeds 5] [--out DIR]

``--quick`` runs every cell tiny (the experiments' ``--quick`` preset: minutes per level,
results mean nothing); ``--help`` lists every flag.
"""

from __future__ import annotations

import dataclasses
import datetime
import os
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated

from tyro.constructors import PrimitiveConstructorSpec

from agents.config import REWARD_MODES
from checker import cli
from experiments.phases import FREE_SETTINGS, config_dict
from experiments.pipeline import Modes, preset, run_experiment
from experiments.presets import BENCHMARK_LEVELS, EXPERIMENTS
from experiments.report.plots import plot_benchmark_level
from experiments.report.tables import BENCHMARK_COLUMNS, benchmark_table
from jaxgrid import rundir
from jaxgrid.io import atomic_write, read_json, to_jsonable, write_json

PROG = "python -m experiments.benchmark"

# ``--levels two_rooms,hazard_rooms``
Levels = Annotated[tuple[str, ...], PrimitiveConstructorSpec(
    nargs=1, metavar="LEVEL[,LEVEL...]", instance_from_str=lambda args: tuple(
        x.strip() for x in args[0].split(",") if x.strip()),
    is_instance=lambda x: isinstance(x, tuple), str_from_instance=lambda v: [",".join(v)],
)]  # fmt: skip


@dataclasses.dataclass(frozen=True)
class BenchmarkConfig:
    """The benchmark; validated on construction (``ValueError`` naming the flag)."""

    levels: Levels = BENCHMARK_LEVELS  # the levels: rows of experiments.presets.EXPERIMENTS
    methods: Modes = REWARD_MODES  # the methods compared: reward modes of agents.config
    # the constrained methods' cost (ExperimentConfig.constrained_cost): "checker", "monitor";
    # None: each method's own (the checker's alarms)
    constrained_cost: str | None = None
    seeds: int = 5  # agents per method and level
    quick: bool = False  # every cell tiny: the outputs in minutes, results mean nothing
    out: str | None = None  # output directory; None: runs/benchmark/<date-time>
    progress: bool = True  # show progress bars
    workers: int = 2  # phases of a level that train at once (ExperimentConfig.workers)

    def __post_init__(self):
        me = type(self).__name__
        # an ablation that sets its own modes (label_timing) compares no methods
        levels = [name for name, row in EXPERIMENTS.items() if "modes" not in row.hidden]
        for name, given, known in (("levels", self.levels, levels),
                                   ("methods", self.methods, REWARD_MODES)):  # fmt: skip
            unknown = [x for x in given if x not in known]
            if unknown or not given or len(set(given)) < len(given):
                raise ValueError(f"{me}.{name}: unknown, repeated or no {name} in {given}; "
                                 f"choose from {','.join(known)}")  # fmt: skip
        for name in ("seeds", "workers"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ValueError(f"{me}.{name} must be an integer >= 1, got {value!r}")
        if self.out is not None and not self.out:
            raise ValueError(f"{me}.out: an output directory is required (omit the flag for "
                             "runs/benchmark/<date-time>)")  # fmt: skip
        for level in self.levels:  # every cell's configuration validates before any compile
            self.experiment(level)

    def experiment(self, level: str):
        """The :class:`~experiments.pipeline.ExperimentConfig` of one level's cell."""
        cfg = preset(EXPERIMENTS[level], "quick" if self.quick else "default")
        out = None if self.out is None else os.path.join(self.out, level)
        return dataclasses.replace(cfg, modes=self.methods, constrained_cost=self.constrained_cost,
                                   seeds=self.seeds, out=out,
                                   progress=self.progress, workers=self.workers,
                                   machine_baseline=False)  # fmt: skip


def parse_args(argv: Sequence[str] | None = None) -> BenchmarkConfig:
    return cli.parse(BenchmarkConfig, argv, prog=PROG, title="benchmark",
                     description="Every method on every benchmark level, one table.")  # fmt: skip


def run_benchmark(cfg: BenchmarkConfig) -> dict:
    """Run (or resume) every level of ``cfg`` in turn, then write the table and pictures;
    returns ``{"levels": {level: results}, "table": ...}``.

    The table and ``benchmark.json`` are written again after every level, with the levels not
    yet done listed as pending, and each level's picture once it is done: a run of many hours
    shows its finished levels while it goes on, and after an interruption."""
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    results, walls = {}, {}
    for i, level in enumerate(cfg.levels):
        print(f"benchmark: level {i + 1}/{len(cfg.levels)} {level} "
              f"({EXPERIMENTS[level].env_id})", file=sys.stderr, flush=True)  # fmt: skip
        start = time.perf_counter()
        results[level] = finished(cfg.experiment(level)) or run_experiment(cfg.experiment(level))
        walls[level] = time.perf_counter() - start
        summary, text = _write_table(cfg, results, walls)
        plot_benchmark_level(summary["levels"][level], level, out / f"{level}.png")
    print(text)
    return {"levels": results, "table": summary}


def _write_table(cfg: BenchmarkConfig, results: dict, walls: dict) -> tuple[dict, str]:
    """``OUT/benchmark.json`` and ``OUT/benchmark.md`` of the levels in ``results``; the rest
    of ``cfg.levels`` is named as pending."""
    out = Path(cfg.out)
    pending = [level for level in cfg.levels if level not in results]
    summary = to_jsonable({"config": dataclasses.asdict(cfg), "columns": list(BENCHMARK_COLUMNS),
               "levels": {level: {"env_id": EXPERIMENTS[level].env_id,
                                  "total_s": r["timing"]["total_s"],
                                  "this_call_s": walls[level],
                                  "methods": {m: _figures(r["methods"][m]) for m in cfg.methods}}
                          for level, r in results.items()},
               "pending": pending})  # fmt: skip
    write_json(out / "benchmark.json", summary)
    text = benchmark_table(summary)
    atomic_write(out / "benchmark.md", text.encode())
    return summary, text


def finished(cfg) -> dict | None:
    """The results of a level's cell that is already done (its ``results.json`` holds every
    method asked for, made with the same configuration), else ``None``: read back, not rerun.
    """
    path = Path(cfg.out) / "results.json"
    if not path.is_file():
        return None
    try:
        results = read_json(path)
    except ValueError:
        return None  # damaged: the pipeline makes it again
    theirs = results.get("config") or {}  # the configuration, and derived keys beside it
    same = all(theirs.get(k) == v for k, v in config_dict(cfg).items() if k not in FREE_SETTINGS)
    if not same or not set(cfg.modes) <= set(results.get("methods", {})):
        return None
    return results


def _figures(entry: dict) -> dict:
    """A method's IQM summaries (``iqm``, ``lo``, ``hi``, ``per_seed``) of the table's
    columns; a column the results do not hold is left out."""
    iqm = entry.get("iqm") or {}
    return {key: iqm[key] for key, _, _ in BENCHMARK_COLUMNS if key in iqm}


def default_out() -> str:
    return os.path.join("runs", "benchmark", datetime.datetime.now().strftime("%Y%m%d-%H%M%S"))


def main(argv: Sequence[str] | None = None) -> dict:
    """``python -m experiments.benchmark`` with ``argv``; Ctrl-C keeps every finished phase,
    and the same command (``--out`` as printed) resumes. ``--out`` is locked for the run."""
    argv = sys.argv[1:] if argv is None else list(argv)
    cfg = parse_args(argv)
    if cfg.out is None:
        cfg = dataclasses.replace(cfg, out=default_out())
    kept = [a for i, a in enumerate(argv) if a != "--out" and not a.startswith("--out=")
            and (i == 0 or argv[i - 1] != "--out")]  # fmt: skip
    resume = shlex.join(["python", "-m", "experiments.benchmark", *kept, "--out", cfg.out])
    with rundir.lock(cfg.out, PROG, resume):
        recorded = Path(cfg.out) / "benchmark_config.json"
        if recorded.exists():  # the same levels' cells: their own config checks say more
            before = read_json(recorded)
            if before.get("seeds") != cfg.seeds or before.get("quick") != cfg.quick:
                raise ValueError(f"--out {cfg.out} holds a benchmark with --seeds "
                                 f"{before.get('seeds')} and --quick {before.get('quick')}; "
                                 "pick a new --out or the same flags to resume it")  # fmt: skip
        write_json(recorded, dataclasses.asdict(cfg))
        return run_benchmark(cfg)


if __name__ == "__main__":
    cli.run_main(main, PROG)
