"""Constraint checker: does the agent's recent trajectory, read with the
constraint's sentence, mean a violation is about to happen?

One mechanism with two kinds behind one protocol:

* :mod:`checker.protocol`: :class:`CheckerProtocol`, what rollout, reward, shield and
  evaluation call on a trained checker of any kind (label timing ``lookahead``, threshold,
  start and step per env on device, candidate scores), and :data:`NO_ACTION`;
* the kinds: :mod:`checker.model`, the window checker (the paper's: its Flax network
  :class:`Checker`, :class:`CheckerConfig` and :class:`TrainedChecker`), and
  :mod:`checker.memory_model`, the memory checker (a GRU over the episode's frames,
  :class:`TrainedMemoryChecker`);
* :mod:`checker.store`: :func:`save` and :func:`load` of a checker of either kind;
* :mod:`checker.reward`: the on-device ring buffer (:func:`init_buffer`, :func:`push`) and
  :func:`violation_prob` of a window checker;
* :mod:`checker.data`: data collected on device and labelled: windows (:func:`collect`),
  streams (:func:`collect_streams`), augmentations, dataset files;
* :mod:`checker.policies`: behaviour policies for collection;
* :mod:`checker.train`: the trainer of each kind (:func:`train_checker`,
  :func:`train_memory_checker`);
* :mod:`checker.metrics`: classification metrics, lead time, :func:`evaluate`,
  :func:`evaluate_streams`;
* :mod:`checker.cli`: the command lines, generated from the configs' dataclasses;
  ``python -m checker --kind window|memory`` trains and measures a checker.

``checker`` imports ``jaxgrid`` only (never ``agents`` or ``experiments``).
"""

from jaxgrid.rundir import prepare_command

prepare_command()  # `python -m checker...`: Ctrl-C and a held --out handled before jax loads
from checker.data import (
    CheckerDataset,
    collect,
    collect_episodes,
    collect_streams,
    relabel,
    with_blocked_counterfactuals,
    with_colour_counterfactuals,
    with_distractors,
)
from checker.memory_model import MemoryCheckerConfig, TrainedMemoryChecker
from checker.metrics import (
    auroc,
    binary_metrics,
    colour_counterfactual,
    evaluate,
    evaluate_streams,
    expected_calibration_error,
    lead_time,
    per_group,
    predict,
    predict_streams,
)
from checker.model import Checker, CheckerConfig, TrainedChecker
from checker.policies import (
    NoisyOracleParams,
    noisy_oracle_policy,
    random_policy,
    with_random_actions,
)
from checker.protocol import NO_ACTION, CheckerProtocol
from checker.reward import init_buffer, push, violation_prob
from checker.store import load, save
from checker.train import (
    CheckerTrainConfig,
    MemoryTrainConfig,
    train_checker,
    train_memory_checker,
)

__all__ = [
    "NO_ACTION",
    "Checker",
    "CheckerProtocol",
    "MemoryCheckerConfig",
    "MemoryTrainConfig",
    "TrainedMemoryChecker",
    "collect_streams",
    "evaluate_streams",
    "predict_streams",
    "relabel",
    "train_memory_checker",
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
