"""One predicted grasp a view (a baseline's), scored as KOSMOS-E's decoded answers are.

    results, rows = view_results(grasps, views, protocol)   # grasps [V, 5] (x, y, w, h, theta)

Each view is an instruction of kind "non" ("grasp any object") in a single scene, answered by every
ground truth left in the view, so the tally's rectangle metric and the protocol's w/h borrowing
(honest: each ground truth's own; paper: the widest opening and the mean jaw) decide as they do for
KOSMOS-E. A baseline gives a grasp, nothing to parse, except under the `public` protocol: there the
public code's detection may find none (a NaN row: a failure, counted in `grasps_not_found`, its
row's grasp None), and the grasp's own w, h and the pixel-count IoU decide (fold_scores.metric_settings).
`views` is any object with `grasps` [V, N, 5], `mask` [V, N], `photo_id` and `copy` (a
baselines.inputs.ViewArrays).
"""

from __future__ import annotations

import numpy as np

from kosmos_jax.instruct.kinds import NON
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.fold_scores import metric_settings
from kosmos_jax.scoring.instructions import Instruction

SCENE = "single"
PART = "grasp"


def view_instructions(views) -> list[Instruction]:
    """One "non" instruction a view, answered by the view's ground truths."""
    return [Instruction(NON, SCENE, "", {PART: row}, np.asarray(views.grasps[row][views.mask[row]], np.float32))
            for row in range(len(views.photo_id))]


def view_results(grasps: np.ndarray, views, protocol: str, backend: str = "exact") -> tuple[dict, list[dict]]:
    """(figures overall and per kind and scene, one row per view with its grasp and whether it succeeds)."""
    grasps = np.asarray(grasps, np.float32)
    if grasps.shape != (len(views.photo_id), 5):
        raise ValueError(f"{grasps.shape[0]} predicted grasps of shape {grasps.shape[1:]} for {len(views.photo_id)} "
                         "views: expected one (x, y, w, h, theta) a view")
    instructions = view_instructions(views)
    success = tally.successes(instructions, grasps, protocol, backend)
    wh_policy, backend = metric_settings(protocol, backend)
    found = np.isfinite(grasps).all(axis=1)
    results = {"accuracy": tally.percent(success), "instructions": len(instructions), "examples": len(instructions),
               "correct": int(success.sum()), "protocol": protocol, "backend": backend, "wh_policy": wh_policy,
               "grasps_not_found": int((~found).sum()),
               "by_kind": tally.group_accuracy(instructions, success, lambda i: i.kind),
               "by_scene": tally.group_accuracy(instructions, success, lambda i: i.scene)}
    rows = [{"example": row, "kind": NON, "scene": SCENE, "part": PART, "photo_ids": [views.photo_id[row]],
             "copy": int(views.copy[row]), "instruction": "",
             "grasp": [round(float(v), 4) for v in grasps[row]] if found[row] else None,
             "ground_truths": int(np.sum(views.mask[row])), "correct": bool(success[row])}
            for row in range(len(instructions))]
    return results, rows
