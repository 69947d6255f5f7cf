"""Fold scores of the rectangle metric under a protocol, reported as mean +- std over folds."""

from __future__ import annotations

import dataclasses

import numpy as np

from kosmos_jax.sources import splits
from kosmos_jax.dataset.views import Views
from kosmos_jax.metrics import grasp_success
from kosmos_jax.scoring.no_learning import ground_truth_mean

WH_POLICY = {"honest": "per_gt", "paper": "kosmos_e"}  # KOSMOS-E's answers: w, h borrowed
# The baselines' own protocol (kosmos_jax.baselines): their grasp keeps its predicted w and h and is
# scored with the public code's pixel-count IoU, whatever backend was asked for.
PUBLIC_METRIC = ("predicted", "reference")


def metric_settings(protocol: str, backend: str = "exact") -> tuple[str, str]:
    """(wh_policy, backend) of the rectangle metric under `protocol`."""
    if protocol == splits.PUBLIC:
        return PUBLIC_METRIC
    if protocol not in WH_POLICY:
        raise ValueError(f"unknown protocol {protocol!r}; expected one of {', '.join(splits.PROTOCOLS)}")
    return WH_POLICY[protocol], backend


@dataclasses.dataclass
class FoldScores:
    per_fold: list[float]  # accuracy in percent, one per fold that has a scorable view
    failures: float  # fraction of answers that did not parse (NaN rows), before any substitution
    views: int  # views scored
    skipped_views: int = 0  # views with no ground truth left in the crop: nothing to score against
    empty_folds: int = 0  # folds with no scored view, left out of the mean and std

    @property
    def mean(self) -> float:
        return float(np.mean(self.per_fold)) if self.per_fold else float("nan")

    @property
    def std(self) -> float:
        return float(np.std(self.per_fold)) if self.per_fold else float("nan")

    def text(self) -> str:
        return f"{self.mean:6.2f} +- {self.std:5.2f}"


def resolve_failures(pred, views: Views, protocol: str):
    """Unparseable answers (rows with a NaN): the paper's code swaps in the ground-truth mean;
    the honest protocol keeps them as failures. Returns (predictions, failure fraction)."""
    pred = np.asarray(pred, np.float32).copy()
    failed = np.isnan(pred).any(axis=-1)
    if protocol == "paper" and failed.any():
        pred[failed] = ground_truth_mean(views.grasps[failed], views.mask[failed])
    return pred, float(failed.mean()) if len(failed) else 0.0


def view_folds(views: Views, scheme: str, protocol: str, object_of: dict | None = None, k: int = 5, seed: int = 0):
    """Fold index of every view: honest folds over photos (or objects), paper folds over views."""
    if protocol == "paper":
        count = len(views.photo_id)
        return splits.paper_image_wise_folds(count, k) if scheme == "image" else splits.paper_object_wise_folds(count, k)
    photo_ids = sorted(set(views.photo_id))
    if scheme == "image":
        folds = splits.image_wise_folds(photo_ids, k, seed)
    else:
        if object_of is None:
            raise ValueError("object-wise folds need the object id of every photo")
        folds = splits.object_wise_folds(photo_ids, [object_of.get(p) for p in photo_ids], k, seed)
    return np.array([folds[p] for p in views.photo_id])


def score(pred, views: Views, folds, protocol: str, backend: str = "exact", k: int = 5) -> FoldScores:
    """Rectangle-metric accuracy per fold of `pred` [V, 3] on `views`. Views without any ground
    truth left in the crop cannot be scored: they are skipped, and a fold left with no view is
    dropped from the mean; both are counted in the result."""
    pred, failures = resolve_failures(pred, views, protocol)
    success = np.asarray(grasp_success(pred, views.grasps, views.mask, backend=backend, wh_policy=WH_POLICY[protocol]))
    scorable = np.asarray(views.mask).any(axis=1)
    folds = np.asarray(folds)
    per_fold = [100.0 * float(success[(folds == f) & scorable].mean()) for f in range(k) if ((folds == f) & scorable).any()]
    return FoldScores(per_fold, failures, int(scorable.sum()), skipped_views=int((~scorable).sum()),
                      empty_folds=k - len(per_fold))
