"""Constraint checker: does the agent's recent trajectory, read with the
constraint's sentence, mean a violation is about to happen?

* :mod:`checker.model`: the window checker, its Flax network (:class:`Checker`,
  :class:`CheckerConfig`) and :class:`TrainedChecker` (params + config pytree);
* :mod:`checker.memory_model`: the memory checker, a GRU over the episode's frames;
* :mod:`checker.store`: :func:`save` and :func:`load` of a checker of either kind;
* :mod:`checker.reward`: the on-device ring buffer (:func:`init_buffer`, :func:`push`) and
  :func:`violation_prob`, what the PPO step calls every env step;
* :mod:`checker.data`: auto-labelled datasets collected on device (:func:`collect`);
* :mod:`checker.policies`: behaviour policies for collection;
* :mod:`checker.train`: :class:`CheckerTrainConfig` and :func:`train_checker`, the one way
  a checker is trained (``python -m checker`` collects noisy-oracle windows and runs it);
* :mod:`checker.cli`: the command lines, generated from the configs' dataclasses;
* :mod:`checker.metrics`: classification metrics, lead time, :func:`evaluate`;

``checker`` imports ``jaxgrid`` only (never ``agents`` or ``experiments``).
"""

from jaxgrid.rundir import interruptible_if_command

interruptible_if_command()  # `python -m checker...`: Ctrl-C handled before jax loads
from checker.data import (
    CheckerDataset,
    collect,
    collect_episodes,
    with_blocked_counterfactuals,
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
from checker.model import Checker, CheckerConfig, TrainedChecker
from checker.policies import (
    NoisyOracleParams,
    noisy_oracle_policy,
    random_policy,
    with_random_actions,
)
from checker.reward import init_buffer, push, violation_prob
from checker.store import load, save
from checker.train import CheckerTrainConfig, train_checker

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
    "CheckerTrainConfig",
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
    "with_blocked_counterfactuals",
    "with_distractors",
    "with_random_actions",
]

