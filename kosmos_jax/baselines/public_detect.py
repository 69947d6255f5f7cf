"""One grasp per view, or none, as GR-ConvNet's and GG-CNN's public code detects it (the `public` protocol).

    grasps, found = detect_grasps(maps)      # GraspMaps [B, H, W] -> [B, 5] (x, y, w, h, theta), bool [B]

Their post-processing (inference/post_process.py of skumra/robotic-grasping, models/common.py of
dougsm/ggcnn), in their order: the angle map 0.5 atan2(sin 2 theta, cos 2 theta) is taken FIRST and
then blurred (sigma 2), so near the +-90 degree wrap the blur averages +89 and -89 degrees towards 0;
the quality map is blurred with sigma 2 and the width map x 150 with sigma 1 (the blur of
baselines.predict: edges extended, cut at 4 sigma, as skimage's `gaussian`).

Their peak (grasp.py's detect_grasps: skimage's peak_local_max(q, min_distance=20, threshold_abs=0.2,
num_peaks=1), whose exclude_border defaults to min_distance): among the pixels that are the maximum of
the 41 x 41 window around them, strictly above 0.2 and at least 20 px from every edge, the highest
one (ties: the first in row-major order, skimage's stable sort). A map where every pixel equals its
window's maximum (a constant map) has no peak, as skimage says. No such pixel: no grasp, `found` is
False and the row is NaN, which the rectangle metric counts as a failure (their evaluation's
empty loop returns False).

The grasp at the peak: its centre (column + 0.5, row + 0.5) in view pixels (our frame: pixel
centres at half-integers), the blurred angle map's value there, the blurred width map's value there
as the opening w, and h = w / 2, their Grasp's jaw. The metric then keeps this w and h
(metrics wh_policy "predicted") and counts pixels ("reference" backend): scoring.fold_scores.metric_settings.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from kosmos_jax import geometry
from kosmos_jax.baselines.layers import GraspMaps
from kosmos_jax.baselines.predict import ANGLE_SIGMA, QUALITY_SIGMA, WIDTH_SIGMA, gaussian_blur
from kosmos_jax.baselines.targets import WIDTH_SCALE

MIN_DISTANCE = 20  # px: peak_local_max's min_distance, and its border (exclude_border=True)
QUALITY_THRESHOLD = 0.2  # threshold_abs: a peak must be strictly above it


def public_maps(maps: GraspMaps, width_scale: float = WIDTH_SCALE):
    """(quality, angle, opening) [B, H, W], blurred in the public code's order (angle after atan2)."""
    quality = gaussian_blur(maps.quality.astype(jnp.float32), QUALITY_SIGMA)
    angle = 0.5 * jnp.arctan2(maps.sin.astype(jnp.float32), maps.cos.astype(jnp.float32))
    opening = maps.width.astype(jnp.float32) * width_scale
    return quality, gaussian_blur(angle, ANGLE_SIGMA), gaussian_blur(opening, WIDTH_SIGMA)


def peak_mask(quality: jax.Array, min_distance: int = MIN_DISTANCE, threshold: float = QUALITY_THRESHOLD,
              border: int = MIN_DISTANCE) -> jax.Array:
    """bool [B, H, W]: the pixels peak_local_max may return (see the module docstring)."""
    size = 2 * min_distance + 1
    # -inf padding: a window running off the edge sees the same maximum as skimage's "nearest" mode
    window_max = jax.lax.reduce_window(quality, -jnp.inf, jax.lax.max, (1, size, size), (1, 1, 1), "SAME")
    is_max = quality == window_max
    trivial = jnp.all(is_max, axis=(1, 2), keepdims=True)
    rows, columns = quality.shape[1:]
    row = jnp.arange(rows)[:, None]
    column = jnp.arange(columns)[None, :]
    inside = (row >= border) & (row < rows - border) & (column >= border) & (column < columns - border)
    return is_max & ~trivial & (quality > threshold) & inside


@functools.partial(jax.jit, static_argnames=("width_scale", "min_distance", "threshold", "border"))
def detect_grasps(maps: GraspMaps, width_scale: float = WIDTH_SCALE, min_distance: int = MIN_DISTANCE,
                  threshold: float = QUALITY_THRESHOLD, border: int = MIN_DISTANCE):
    """(grasps [B, 5] (x, y, w, h, theta) in view pixels, NaN rows where no peak; found [B] bool)."""
    quality, angle, opening = public_maps(maps, width_scale)
    candidates = peak_mask(quality, min_distance, threshold, border)
    batch, _, columns = quality.shape
    flat = jnp.where(candidates, quality, -jnp.inf).reshape(batch, -1)
    peak = jnp.argmax(flat, axis=-1)  # the first of equal maxima, as skimage's stable sort
    found = jnp.any(candidates, axis=(1, 2))

    def at_peak(image):
        return jnp.take_along_axis(image.reshape(batch, -1), peak[:, None], axis=-1)[:, 0]

    width = at_peak(opening)
    x = (peak % columns).astype(jnp.float32) + 0.5
    y = (peak // columns).astype(jnp.float32) + 0.5
    grasps = jnp.stack([x, y, width, width / 2, geometry.normalize_angle(at_peak(angle))], axis=-1)
    return jnp.where(found[:, None], grasps, jnp.nan), found


__all__ = ["MIN_DISTANCE", "QUALITY_THRESHOLD", "detect_grasps", "peak_mask", "public_maps"]
