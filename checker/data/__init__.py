"""Checker data, split by job:

* :mod:`checker.data.streams`: windows collected on device under a behaviour policy
  (:func:`collect`, :func:`collect_episodes`);
* :mod:`checker.data.labels`: what a window's label says (:func:`compute_labels`, the label
  horizon ``lookahead``, :func:`validate_window`);
* :mod:`checker.data.augment`: rows whose labels are known without a rollout
  (:func:`with_colour_counterfactuals`, :func:`with_blocked_counterfactuals`,
  :func:`with_distractors`);
* :mod:`checker.data.files`: :class:`CheckerDataset` and its files.
"""

from checker.data.augment import (
    before_step,
    front_cells,
    with_blocked_counterfactuals,
    with_colour_counterfactuals,
    with_distractors,
)
from checker.data.files import CheckerDataset
from checker.data.labels import compute_labels, validate_window
from checker.data.streams import collect, collect_episodes

__all__ = [
    "CheckerDataset",
    "collect",
    "collect_episodes",
    "compute_labels",
    "validate_window",
    "with_blocked_counterfactuals",
    "with_colour_counterfactuals",
    "before_step",
    "front_cells",
    "with_distractors",
]
