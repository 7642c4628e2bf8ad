"""Checker data, split by job:

* :mod:`checker.data.streams`: windows (the window checker's, :func:`collect`,
  :func:`collect_episodes`) and whole streams (the memory checker's, :func:`collect_streams`)
  collected on device under a behaviour policy;
* :mod:`checker.data.labels`: what a label says (:func:`compute_labels`, the label horizon
  ``lookahead``, :func:`validate_window`, :func:`relabel` of streams);
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
from checker.data.labels import compute_labels, relabel, validate_window
from checker.data.streams import BEHAVIOUR, collect, collect_episodes, collect_streams

__all__ = [
    "BEHAVIOUR",
    "CheckerDataset",
    "collect",
    "collect_episodes",
    "collect_streams",
    "relabel",
    "compute_labels",
    "validate_window",
    "with_blocked_counterfactuals",
    "with_colour_counterfactuals",
    "before_step",
    "front_cells",
    "with_distractors",
]
