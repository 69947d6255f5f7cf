"""The opening and jaw size of a predicted grasp whose answer does not state them (XYA answers).

A new photo has no ground truth to borrow them from, so the predictor borrows the protocol's
size (scoring.grasp_size) of the run's own training views, averaged: what the metric would
have lent a prediction on a typical training view. Measured on at most SAMPLED examples spread
evenly over the split. Without the run's dataset (or for an imported folder) CORNELL_SIZE stands in.
"""

from __future__ import annotations

import warnings

import numpy as np

from kosmos_jax.scoring.grasp_size import borrowed_size
from kosmos_jax.workdir.files import RunError

SAMPLED = 512
# Mean opening and jaw, in pixels, of Cornell's positive rectangles, measured on the 100 photos of
# ../shared/data/cornell (483 rectangles); the views keep the photos' scale.
CORNELL_SIZE = (37.1, 24.6)


def training_size(examples, protocol: str, sampled: int = SAMPLED) -> tuple[float, float]:
    """Mean borrowed (w, h) over examples of a split (records holding "answers")."""
    if not len(examples):
        raise ValueError("no training examples to measure grasp sizes on")
    rows = np.unique(np.linspace(0, len(examples) - 1, min(len(examples), sampled)).astype(int))
    sizes = np.array([borrowed_size(examples[int(i)]["answers"], protocol) for i in rows])
    sizes = sizes[np.isfinite(sizes).all(axis=1)]
    if not len(sizes):
        raise ValueError("the training examples hold no finite grasp")
    return float(sizes[:, 0].mean()), float(sizes[:, 1].mean())


def run_grasp_size(run) -> tuple[float, float]:
    """The protocol's borrowed size over a run's (workdir.run.Run) training views; Cornell's when its
    dataset is gone."""
    try:
        return training_size(run.split("train").examples, run.protocol)
    except (RunError, ValueError) as error:
        warnings.warn(f"grasp sizes not measured on the run's training views ({error}); using Cornell's mean "
                      f"opening and jaw {CORNELL_SIZE}", stacklevel=3)
        return CORNELL_SIZE
