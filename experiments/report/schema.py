"""The ``results.json`` contract: what an experiment's results hold, and their check.

- :data:`MODES`, :data:`MODE_LABELS` and :func:`ordered_modes`: the reward modes, their names
  and the order every table and figure shows them in.
- :data:`CHECKER_METRICS`, :data:`CHECKER_SPLITS` and :func:`checker_rates`: the learned
  checker's rates, its splits, and its metrics as ``results.json`` holds them.
- :data:`RESULTS_SCHEMA` and :func:`validate_results`: the shape of ``results.json``, checked
  before anything is written.
- :data:`COST_KEYS`: the evaluations' cost metrics, optional in ``final`` (results written
  before them lack them, and still validate and render).

Conventions for the optional extras that the report understands (all other extra keys are
allowed and passed through untouched):

- ``methods.<mode>.final_per_seed``: ``{"violation_rate": [S], "mean_reward": [S],
  "success_rate": [S]}`` and the :data:`COST_KEYS` (any subset). When present (and ``iqm``
  is not) the table shows ``mean ± CI half-width``.
- ``methods.<mode>.iqm``: ``{metric: {"iqm", "lo", "hi", "per_seed"}}``
  (:func:`experiments.stats.summary`); the table shows ``IQM [lo, hi]``.
- ``methods.<mode>.final_unshielded``: the shield modes' policy evaluated without its shield.
- ``comparisons``: ``{name: {"p", "lo", "hi"}}`` probabilities of improvement.
- ``methods.<mode>.curve_per_seed``: ``{"step": [T], "violation_rate": [S][T],
  "mean_reward": [S][T], "success_rate": [S][T]}`` (and the :data:`COST_KEYS` and
  ``"training_cost_rate": [S][T]``), read by
  :func:`experiments.report.plots.curves_from_results`.
- ``methods.<mode>.training_cost_rate`` (and ``_per_seed``): OmniSafe's cost rate, the env
  cost of every training step over the number of steps, from the first update to the last;
  ``training_cost_per_seed``: that cost; ``training_violations_per_seed``: the violations.
- ``checker.transfer``: a metrics dict like ``checker.test`` (e.g. the 2Rooms checker on
  3Rooms-Key), or null.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from agents.config import REWARD_MODES

__all__ = [
    "CHECKER_METRICS",
    "CHECKER_SPLITS",
    "COST_KEYS",
    "MODES",
    "MODE_LABELS",
    "RATE_KEYS",
    "RESULTS_SCHEMA",
    "checker_rates",
    "ordered_modes",
    "validate_results",
]

#: The reward/cost modes, in the display order of tables and figures.
MODES: tuple[str, ...] = REWARD_MODES

#: The name of each mode in tables and legends.
MODE_LABELS: dict[str, str] = {
    "checker": "checker-shaped",
    "shaped": "ground-truth shaped",
    "none": "unconstrained",
    "lagrangian": "PPO-Lagrangian",
    "pid_lagrangian": "PID Lagrangian",
    "saute": "Saute",
    "cpo": "CPO",
    "focops": "FOCOPS",
    "shield": "checker shield",
    "shield_monitor": "monitor shield",
}

#: Metrics of the learned checker, all in [0, 1].
CHECKER_METRICS: tuple[str, ...] = ("accuracy", "precision", "recall", "f1", "auroc", "ece")
#: Checker evaluation splits shown in the table; ``test`` is required, the others may be null.
CHECKER_SPLITS: tuple[str, ...] = ("test", "heldout", "transfer")

_FINAL_KEYS = ("violation_rate", "mean_reward", "success_rate", "episodes")
#: The evaluations' cost metrics (:func:`agents.evaluation.summarise`): the mean episode cost,
#: and the longest run of consecutive costly steps of an episode, its mean and its maximum over
#: the episodes (pooled over seeds: the maximum of theirs). Each a float >= 0.
COST_KEYS: tuple[str, ...] = ("mean_cost", "mean_costly_run", "max_costly_run")
_CURVE_KEYS = ("step", "violation_rate", "mean_reward", "success_rate")
#: The per-method metrics that are rates (in [0, 1]); ``mean_reward`` is any finite real.
RATE_KEYS = frozenset({"violation_rate", "success_rate"})

#: Human-readable description of ``results.json``. ``"rate"`` = float in [0, 1]; ``"float"`` =
#: finite real; ``"int>=k"`` = integer >= k; ``"... | null"`` = may be null. Extra keys are
#: allowed everywhere.
RESULTS_SCHEMA: dict[str, Any] = {
    "experiment": "str (non-empty)",
    "config": "object (free-form run configuration)",
    "checker": {
        "test": {m: "rate" for m in CHECKER_METRICS},
        "heldout": "same as test | null (key required; null when not measured)",
        "transfer": "optional: same as test | null",
        "shield": "optional: the shield's own checker: {test: same as test, guided: rate, "
        "auroc_by}",
    },
    "methods": {
        "<mode in checker|shaped|none|lagrangian|shield|shield_monitor> (at least one)": {
            "final": {
                "violation_rate": "rate",
                "mean_reward": "float",
                "success_rate": "rate",
                "episodes": "int>=1",
                **{k: "optional: float>=0" for k in COST_KEYS},
            },
            "training_violations": "int>=0 (counted from the first update)",
            "training_violations_per_seed": "optional: [int>=0] (one per seed)",
            "training_cost_rate": "optional: float>=0 (env cost over env steps of training)",
            "training_cost_rate_per_seed": "optional: [float>=0] (one per seed)",
            "training_cost_per_seed": "optional: [float>=0] (one per seed)",
            "curve": [
                {
                    "step": "int>=0 (non-decreasing along the list)",
                    "violation_rate": "rate",
                    "mean_reward": "float",
                    "success_rate": "rate",
                }
            ],
            "seeds": "int>=1",
            "final_per_seed": f"optional: {{violation_rate|mean_reward|success_rate|"
            f"{'|'.join(COST_KEYS)}: [seeds]}}",
        }
    },
    "timing": {"total_s": "float>=0"},
    "code": "optional: [{sha256, versions, git, first_used}] every code that wrote the run",
}


def checker_rates(metrics: Mapping) -> dict:
    """The :data:`CHECKER_METRICS` of ``metrics`` (a checker evaluation) as ``results.json``
    holds them; undefined ones (no predicted positives, one class) become 0 for precision/F1
    (the usual zero-division convention) and 0.5 for AUROC."""
    fill = {"auroc": 0.5}
    return {k: float(metrics[k]) if metrics[k] is not None else fill.get(k, 0.0)
            for k in CHECKER_METRICS}  # fmt: skip


def ordered_modes(modes: Any) -> list[str]:
    """``modes`` in the display order: those of :data:`MODES` in its order, then the others."""
    modes = list(modes)
    return [m for m in MODES if m in modes] + [m for m in modes if m not in MODES]


def _is_int(x: Any) -> bool:
    if isinstance(x, bool | np.bool_):
        return False
    return isinstance(x, numbers.Integral)


def _is_real(x: Any) -> bool:
    return (
        isinstance(x, numbers.Real)
        and not isinstance(x, bool | np.bool_)
        and math.isfinite(float(x))
    )


def _fmt(x: Any) -> str:
    s = repr(x)
    return s if len(s) <= 60 else s[:57] + "..."


def _require_mapping(d: Any, path: str) -> Mapping:
    if not isinstance(d, Mapping):
        raise ValueError(f"{path}: expected an object, got {type(d).__name__} {_fmt(d)}")
    return d


def _get(d: Mapping, key: str, path: str) -> Any:
    if key not in d:
        raise ValueError(f"{path + '.' if path else ''}{key}: missing required key")
    return d[key]


def _check_rate(x: Any, path: str) -> None:
    if not _is_real(x) or not 0.0 <= float(x) <= 1.0:
        raise ValueError(f"{path}: expected a float in [0, 1], got {_fmt(x)}")


def _check_real(x: Any, path: str, minimum: float | None = None) -> None:
    if not _is_real(x):
        raise ValueError(f"{path}: expected a finite float, got {_fmt(x)}")
    if minimum is not None and float(x) < minimum:
        raise ValueError(f"{path}: expected a float >= {minimum}, got {_fmt(x)}")


def _check_int(x: Any, path: str, minimum: int) -> None:
    if not _is_int(x) or int(x) < minimum:
        raise ValueError(f"{path}: expected an int >= {minimum}, got {_fmt(x)}")


def _check_nonnegative(x: Any, path: str) -> None:
    _check_real(x, path, minimum=0.0)


def _check_count(x: Any, path: str) -> None:
    _check_int(x, path, 0)


def _check_seed_values(vals: Any, path: str, seeds: int, check) -> None:
    """A list of one value per seed, each passing ``check(value, path)``."""
    if not isinstance(vals, Sequence | np.ndarray) or isinstance(vals, str):
        raise ValueError(f"{path}: expected a list, got {_fmt(vals)}")
    if len(vals) != seeds:
        raise ValueError(f"{path}: expected {seeds} values (one per seed), got {len(vals)}")
    for j, v in enumerate(vals):
        check(v, f"{path}[{j}]")


def _check_metrics(m: Any, path: str) -> None:
    m = _require_mapping(m, path)
    for k in CHECKER_METRICS:
        _check_rate(_get(m, k, path), f"{path}.{k}")


def validate_results(results: dict) -> None:
    """Check ``results`` against :data:`RESULTS_SCHEMA`; return None or raise ``ValueError``.

    The message starts with the dotted key path of the first offending value, e.g.
    ``methods.checker.final.violation_rate: expected a float in [0, 1], got 1.3``. Numpy
    scalars are accepted (validation may run before JSON serialisation); NaN/inf are not.
    """
    _require_mapping(results, "<results>")
    exp = _get(results, "experiment", "")
    if not isinstance(exp, str) or not exp:
        raise ValueError(f"experiment: expected a non-empty str, got {_fmt(exp)}")
    _require_mapping(_get(results, "config", ""), "config")

    chk = _require_mapping(_get(results, "checker", ""), "checker")
    _check_metrics(_get(chk, "test", "checker"), "checker.test")
    if _get(chk, "heldout", "checker") is not None:
        _check_metrics(chk["heldout"], "checker.heldout")
    if chk.get("transfer") is not None:
        _check_metrics(chk["transfer"], "checker.transfer")
    if chk.get("shield") is not None:
        shield = _require_mapping(chk["shield"], "checker.shield")
        _check_metrics(_get(shield, "test", "checker.shield"), "checker.shield.test")

    methods = _require_mapping(_get(results, "methods", ""), "methods")
    if not methods:
        raise ValueError("methods: expected at least one mode, got an empty object")
    for mode, entry in methods.items():
        p = f"methods.{mode}"
        if mode not in MODES:
            raise ValueError(f"{p}: unknown mode {mode!r}; expected one of {', '.join(MODES)}")
        entry = _require_mapping(entry, p)

        final = _require_mapping(_get(entry, "final", p), f"{p}.final")
        for k in _FINAL_KEYS:
            v = _get(final, k, f"{p}.final")
            if k == "episodes":
                _check_int(v, f"{p}.final.episodes", 1)
            elif k in RATE_KEYS:
                _check_rate(v, f"{p}.final.{k}")
            else:
                _check_real(v, f"{p}.final.{k}")
        for k in COST_KEYS:
            if k in final:
                _check_nonnegative(final[k], f"{p}.final.{k}")

        _check_int(_get(entry, "training_violations", p), f"{p}.training_violations", 0)
        _check_int(_get(entry, "seeds", p), f"{p}.seeds", 1)
        seeds = int(entry["seeds"])
        if entry.get("training_cost_rate") is not None:
            _check_nonnegative(entry["training_cost_rate"], f"{p}.training_cost_rate")
        for k, check in (("training_violations_per_seed", _check_count),
                         ("training_cost_rate_per_seed", _check_nonnegative),
                         ("training_cost_per_seed", _check_nonnegative)):  # fmt: skip
            if entry.get(k) is not None:
                _check_seed_values(entry[k], f"{p}.{k}", seeds, check)

        curve = _get(entry, "curve", p)
        if not isinstance(curve, Sequence) or isinstance(curve, str | bytes):
            raise ValueError(f"{p}.curve: expected a list of points, got {_fmt(curve)}")
        prev_step = -1
        for i, point in enumerate(curve):
            pp = f"{p}.curve[{i}]"
            point = _require_mapping(point, pp)
            for k in _CURVE_KEYS:
                v = _get(point, k, pp)
                if k == "step":
                    _check_int(v, f"{pp}.step", 0)
                    if int(v) < prev_step:
                        raise ValueError(
                            f"{pp}.step: steps must be non-decreasing, got {int(v)} after "
                            f"{prev_step}"
                        )
                    prev_step = int(v)
                elif k in RATE_KEYS:
                    _check_rate(v, f"{pp}.{k}")
                else:
                    _check_real(v, f"{pp}.{k}")

        if entry.get("final_per_seed") is not None:
            pp = f"{p}.final_per_seed"
            fps = _require_mapping(entry["final_per_seed"], pp)
            for k, vals in fps.items():
                if k in RATE_KEYS:
                    _check_seed_values(vals, f"{pp}.{k}", seeds, _check_rate)
                elif k == "mean_reward":
                    _check_seed_values(vals, f"{pp}.{k}", seeds, _check_real)
                elif k in COST_KEYS:
                    _check_seed_values(vals, f"{pp}.{k}", seeds, _check_nonnegative)
                # extra per-seed arrays are allowed

    timing = _require_mapping(_get(results, "timing", ""), "timing")
    _check_real(_get(timing, "total_s", "timing"), "timing.total_s", minimum=0.0)
