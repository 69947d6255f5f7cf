"""The opening w and jaw size h a predicted (x, y, theta) is drawn with, borrowed from ground truths
the way the protocol's metric borrows them (DESIGN.md section 3).

paper: the widest opening and the mean jaw of the view's ground truths (KOSMOS-E's code).
honest: the metric takes each ground truth's own w, h in turn; one drawing takes their mean.
"""

from __future__ import annotations

import numpy as np

from kosmos_jax.scoring.fold_scores import WH_POLICY


def borrowed_size(truths, protocol: str) -> tuple[float, float]:
    """(w, h) for a prediction on a view whose ground truths are `truths` [N, 5] (NaN rows ignored);
    NaN when there is none."""
    if protocol not in WH_POLICY:
        raise ValueError(f"unknown protocol {protocol!r}; expected one of {sorted(WH_POLICY)}")
    truths = np.asarray(truths, np.float64).reshape(-1, 5)
    truths = truths[np.isfinite(truths).all(axis=1)]
    if not len(truths):
        return float("nan"), float("nan")
    width = truths[:, 2].max() if protocol == "paper" else truths[:, 2].mean()
    return float(width), float(truths[:, 3].mean())
