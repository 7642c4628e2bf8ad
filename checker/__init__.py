"""Constraint checker (DESIGN.md §6): does the agent's recent trajectory, read with the
constraint's sentence, mean a violation is about to happen?

* :mod:`checker.model`: the Flax network (:class:`Checker`, :class:`CheckerConfig`);
* :mod:`checker.trained`: :class:`TrainedChecker` (params + config pytree), :func:`save`,
  :func:`load`;
* :mod:`checker.reward`: the on-device ring buffer (:func:`init_buffer`, :func:`push`) and
  :func:`violation_prob`, what the PPO step calls every env step;
* :mod:`checker.data`: auto-labelled datasets collected on device (:func:`collect`);
* :mod:`checker.policies`: behaviour policies for collection;
* :mod:`checker.train`: :func:`train_checker` and the ``python -m checker.train`` CLI;
* :mod:`checker.metrics`: classification metrics, lead time, :func:`evaluate`;
* :mod:`checker.bench`: the checker's cost per env step (``python -m checker.bench``).

``checker`` imports ``jaxgrid`` only (never ``agents`` or ``experiments``).
"""

from checker.data import (
    CheckerDataset,
    collect,
    collect_episodes,
    with_colour_counterfactuals,
    with_distractors,
)
from checker.metrics import (
    auroc,
    binary_metrics,
    colour_counterfactual,
    evaluate,
    expected_calibration_error,
    lead_time,
    per_group,
    predict,
)
from checker.model import Checker, CheckerConfig
from checker.policies import NoisyOracleParams, noisy_oracle_policy, random_policy
from checker.reward import init_buffer, push, violation_prob
from checker.trained import TrainedChecker, load, save

__all__ = [
    "Checker",
    "auroc",
    "binary_metrics",
    "colour_counterfactual",
    "evaluate",
    "expected_calibration_error",
    "lead_time",
    "per_group",
    "predict",
    "train_checker",
    "CheckerConfig",
    "CheckerDataset",
    "NoisyOracleParams",
    "TrainedChecker",
    "collect",
    "collect_episodes",
    "init_buffer",
    "load",
    "noisy_oracle_policy",
    "push",
    "random_policy",
    "save",
    "violation_prob",
    "with_colour_counterfactuals",
    "with_distractors",
]


def __getattr__(name):
    # Lazy, so that ``python -m checker.train`` does not find checker.train already imported
    # (runpy's RuntimeWarning) when the package is loaded first.
    if name == "train_checker":
        from checker.train import train_checker

        return train_checker
    raise AttributeError(f"module 'checker' has no attribute {name!r}")
