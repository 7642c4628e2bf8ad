"""Reporting of the paper-reproduction experiments, one module per job:

- :mod:`experiments.report.schema`: the ``results.json`` contract and its check;
- :mod:`experiments.report.plots`: the learning-curve and sweep figures;
- :mod:`experiments.report.tables`: the Markdown tables (of one run and of a sweep),
  ``results.json`` + ``results.md``, and the console summary.

The statistics they show (IQM, bootstrap and Student-t intervals) are
:mod:`experiments.stats`'. Importing the report loads neither matplotlib nor ``scipy.stats``:
each is imported by the function that needs it.
"""

from experiments.report.plots import MODE_COLORS, curves_from_results, plot_curves, plot_sweep
from experiments.report.schema import (
    CHECKER_METRICS,
    CHECKER_SPLITS,
    COST_KEYS,
    MODE_LABELS,
    MODES,
    RESULTS_SCHEMA,
    checker_rates,
    validate_results,
)
from experiments.report.tables import (
    ReportPaths,
    results_table,
    summarise,
    sweep_table,
    write_report,
)

__all__ = [
    "CHECKER_METRICS",
    "CHECKER_SPLITS",
    "COST_KEYS",
    "MODES",
    "MODE_COLORS",
    "MODE_LABELS",
    "RESULTS_SCHEMA",
    "ReportPaths",
    "checker_rates",
    "curves_from_results",
    "plot_curves",
    "plot_sweep",
    "results_table",
    "summarise",
    "sweep_table",
    "validate_results",
    "write_report",
]
