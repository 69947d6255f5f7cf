"""Which of a sample's answering grasps become its targets (FormatConfig.target_grasp):
- "first": row 0 (for angle and part instructions the grasp the sentence was made from);
- "each": one example per grasp;
- "random": one, drawn with the given generator;
- "top": one, a function of the grasps' centres: the grasp nearest the point that lies one spread above
  their mean, so a ring answers with its top, a bar lying across the view with its middle, and the answer
  to an angle question asked without the location is one angle, not a mixture of the angles around a rim;
- "consensus": one, the grasp that, answered as a prediction, hits the most of the sample's grasps under
  the honest rectangle metric, the first on a tie: where the annotation's grasps crowd, a mug's handle
  rather than its body's grasps at random angles. As make demo's fine-tune target it changed nothing
  beyond the seeds' spread (results/annotation_draws). It scores N x N pairs through the jit metric,
  one compile for each grasp count met: 4,800 random sets of 2 to 7 grasps took 3.1 s after 9.9 s for the
  first 50 (2 cores, beside a training run, 2026-12-06).
"""

from __future__ import annotations

import numpy as np

from kosmos_jax.metrics.success import grasp_success

TARGET_CHOICES = ("first", "each", "random", "top", "consensus")


def top_row(grasps: np.ndarray) -> int:
    """The row of the grasp nearest mean(centres) - (0, spread), spread the largest distance of a centre from
    the mean (image y grows downwards); the first such row on a tie."""
    centres = np.asarray(grasps, np.float64)[:, :2]
    mean = centres.mean(axis=0)
    spread = float(np.max(np.linalg.norm(centres - mean, axis=1)))
    return int(np.argmin(np.linalg.norm(centres - (mean - np.array([0.0, spread])), axis=1)))


def consensus_row(grasps: np.ndarray) -> int:
    """The row of the grasp whose (x, y, theta), as a prediction, hits the most of `grasps` [N, 5] (the
    rectangle metric with each one's own w and h, as the honest protocol scores); the first such row on a tie."""
    grasps = np.asarray(grasps, np.float32)
    count = len(grasps)
    predictions = np.repeat(grasps[:, [0, 1, 4]], count, axis=0)  # row i * count + j: grasp i against grasp j
    hits = grasp_success(predictions, np.tile(grasps, (count, 1))[:, None], np.ones((count * count, 1), bool))
    return int(np.argmax(np.asarray(hits).reshape(count, count).sum(axis=1)))


def chosen_rows(grasps: np.ndarray, choice: str, rng: np.random.Generator | None) -> list[int]:
    """The rows of `grasps` [N, 5] that become targets under `choice` (TARGET_CHOICES)."""
    count = grasps.shape[0]
    if choice == "top":
        return [top_row(grasps)]
    if choice == "consensus":
        return [consensus_row(grasps)]
    if choice == "first":
        return [0]
    if choice == "each":
        return list(range(count))
    if rng is None:
        raise ValueError("target_grasp='random' needs a numpy Generator")
    return [int(rng.integers(count))]
