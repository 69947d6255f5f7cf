"""The rectangle metric: a predicted grasp is correct when, for at least one ground truth of the
image, the angle difference modulo pi is at most 30 degrees and the IoU is above 0.25.

The prediction gives (x, y, theta); its w and h come from the ground truth, by one of two policies:
- "per_gt" (the honest protocol): w, h borrowed from each ground truth in turn;
- "kosmos_e" (the paper's code): w = the largest opening of the image, h = the mean jaw size.
A [B, 5] prediction may also keep its own w, h with "predicted".
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp

from kosmos_jax import geometry
from kosmos_jax.metrics.exact_iou import exact_iou, unstack
from kosmos_jax.metrics.reference_iou import reference_iou

BACKENDS = ("exact", "reference")
WH_POLICIES = ("per_gt", "kosmos_e", "predicted")
# Angles compared in float32 pick up rounding from the modulo; 1e-6 rad (6e-5 degrees) absorbs it.
ANGLE_TOLERANCE = 1e-6


def _check(name, value, allowed):
    if value not in allowed:
        raise ValueError(f"unknown {name} {value!r}; expected one of {allowed}")


def rectangle_iou(a, b, backend: str = "exact", max_rows: int = 512):
    """IoU of rotated rectangles, arrays [..., 5] of (x, y, w, h, theta) that broadcast.

    backend "exact": polygon clipping (float32 by default, float64 when x64 is on).
    backend "reference": count of integer pixel centres, as the public GG-CNN / KOSMOS-E code; NaN
    for a rectangle spanning more than `max_rows` rows.
    """
    _check("backend", backend, BACKENDS)
    a, b = jnp.asarray(a), jnp.asarray(b)
    if a.shape[-1:] != (5,) or b.shape[-1:] != (5,):
        raise ValueError(f"rectangles must be [..., 5] (x, y, w, h, theta); got {a.shape} and {b.shape}")
    if backend == "exact":
        return _exact_iou_jit(a, b)
    return _reference_iou_jit(a, b, max_rows)


_exact_iou_jit = jax.jit(exact_iou)
_reference_iou_jit = jax.jit(reference_iou, static_argnums=2)


def _borrowed_size(pred, gts, gt_mask, wh_policy):
    """[B, M, 2] (w, h) of the prediction against each ground truth, by the w/h policy."""
    if wh_policy == "per_gt":
        wh = gts[..., 2:4]
    elif wh_policy == "kosmos_e":
        count = jnp.maximum(jnp.sum(gt_mask, axis=1, keepdims=True), 1)
        widest = jnp.max(jnp.where(gt_mask, gts[..., 2], -jnp.inf), axis=1, keepdims=True, initial=-jnp.inf)
        mean_jaw = jnp.sum(jnp.where(gt_mask, gts[..., 3], 0.0), axis=1, keepdims=True) / count
        wh = jnp.broadcast_to(jnp.stack([widest, mean_jaw], axis=-1), gts[..., 2:4].shape)
    else:
        if pred.shape[-1] != 5:
            raise ValueError("wh_policy 'predicted' needs predictions [B, 5] (x, y, w, h, theta)")
        wh = jnp.broadcast_to(pred[:, None, 2:4], gts[..., 2:4].shape)
    return wh


def predicted_rectangles(pred, gts, gt_mask, wh_policy: str):
    """[B, M, 5] rectangles to compare with each ground truth, after the w/h policy."""
    _check("wh_policy", wh_policy, WH_POLICIES)
    xy = pred[:, None, 0:2]
    theta = pred[:, None, -1:]
    wh = _borrowed_size(pred, gts, gt_mask, wh_policy)
    xy = jnp.broadcast_to(xy, gts[..., 0:2].shape)
    theta = jnp.broadcast_to(theta, gts[..., 4:5].shape)
    return jnp.concatenate([xy, wh, theta], axis=-1)


@functools.partial(jax.jit, static_argnames=("backend", "wh_policy", "max_rows"))
def _success(pred, gts, gt_mask, angle_threshold, iou_threshold, backend, wh_policy, max_rows):
    if backend == "exact":  # fields kept apart: no [B, M, 5] array is built
        wh = _borrowed_size(pred, gts, gt_mask, wh_policy)
        iou = exact_iou((pred[:, None, 0], pred[:, None, 1], wh[..., 0], wh[..., 1], pred[:, None, -1]), unstack(gts))
    else:
        iou = reference_iou(predicted_rectangles(pred, gts, gt_mask, wh_policy), gts, max_rows)
    angle_ok = geometry.angle_difference(pred[:, None, -1], gts[..., 4]) <= angle_threshold + ANGLE_TOLERANCE
    # One reduction serves both outputs (a second one over the IoU splits XLA's fusion); `initial`
    # makes it defined for M = 0, where no prediction succeeds.
    best = jnp.max(jnp.where(gt_mask & angle_ok & ~jnp.isnan(iou), iou, -1.0), axis=1, initial=-1.0)
    return best > iou_threshold, jnp.maximum(best, 0.0)


def grasp_success(
    pred,
    gts,
    gt_mask,
    backend: str = "exact",
    wh_policy: str = "per_gt",
    angle_threshold_deg: float = 30.0,
    iou_threshold: float = 0.25,
    max_rows: int = 512,
    return_iou: bool = False,
):
    """Rectangle-metric success per image.

    pred [B, 3] (x, y, theta) or [B, 5]; gts [B, M, 5] padded; gt_mask [B, M] marks real ones.
    A prediction with a NaN (an unparseable answer) is a failure, and so is every prediction when
    M = 0. Returns bool [B], and with `return_iou` also the best IoU among angle-passing ground
    truths (0 when none).
    """
    _check("backend", backend, BACKENDS)
    _check("wh_policy", wh_policy, WH_POLICIES)
    pred, gts, gt_mask = jnp.asarray(pred), jnp.asarray(gts), jnp.asarray(gt_mask, bool)
    if pred.ndim != 2 or pred.shape[-1] not in (3, 5):
        raise ValueError(f"pred must be [B, 3] (x, y, theta) or [B, 5]; got {pred.shape}")
    if gts.ndim != 3 or gts.shape[-1] != 5 or gts.shape[0] != pred.shape[0]:
        raise ValueError(f"gts must be [B, M, 5] with B = {pred.shape[0]}; got {gts.shape}")
    if gt_mask.shape != gts.shape[:2]:
        raise ValueError(f"gt_mask must be {gts.shape[:2]}; got {gt_mask.shape}")
    dtype = gts.dtype if jnp.issubdtype(gts.dtype, jnp.floating) else jnp.float32
    success, best = _success(
        pred.astype(dtype), gts.astype(dtype), gt_mask,
        jnp.asarray(math.radians(angle_threshold_deg), dtype), jnp.asarray(iou_threshold, dtype),
        backend, wh_policy, max_rows,
    )
    return (success, best) if return_iou else success
