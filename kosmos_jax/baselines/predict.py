"""One grasp per view from a generative network's four maps: the peak of the smoothed quality map.

    grasps, quality = predict_grasps(maps)     # GraspMaps [B, H, W] -> [B, 5] (x, y, w, h, theta), [B]

Post-processing as GG-CNN / GR-ConvNet describe it: a Gaussian blur of sigma 2 on the quality map,
sigma 2 on the angle, sigma 1 on the width (edges extended, the kernel cut at 4 sigma, as skimage's
`gaussian` does); the grasp is the quality map's highest pixel, its centre (column + 0.5, row + 0.5)
in view pixels, its angle 0.5 atan2(sin 2 theta, cos 2 theta) and its opening the width map x 150 at
that pixel. Two differences from the public code (see the package docstring): the blur of sigma 2
goes on cos 2 theta and sin 2 theta BEFORE the angle is taken, not on the angle map (which averages
+89 and -89 degrees into 0), and the peak is the plain argmax over the whole view: always one grasp,
border pixels included, no 0.2 quality threshold (the peak's quality is returned for a caller that
wants one). The jaw size h is half the predicted opening, the public code's convention; the
metric borrows w and h from the ground truth under either protocol (kosmos_jax.metrics), so h
matters only with its "predicted" policy. Jit-compiled and batched.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.baselines.layers import GraspMaps
from kosmos_jax.baselines.targets import WIDTH_SCALE

QUALITY_SIGMA = 2.0
ANGLE_SIGMA = 2.0
WIDTH_SIGMA = 1.0
TRUNCATE = 4.0


def gaussian_taps(sigma: float, truncate: float = TRUNCATE) -> np.ndarray:
    """The normalised 1-D Gaussian kernel of radius int(truncate * sigma + 0.5) (scipy's)."""
    radius = int(truncate * sigma + 0.5)
    offsets = np.arange(-radius, radius + 1, dtype=np.float64)
    taps = np.exp(-0.5 * (offsets / sigma) ** 2)
    return (taps / taps.sum()).astype(np.float32)


def gaussian_blur(maps: jax.Array, sigma: float) -> jax.Array:
    """Blur [..., H, W] maps along H and W, the edge pixels extended ("nearest"). sigma 0: unchanged."""
    if sigma <= 0:
        return maps
    taps = gaussian_taps(sigma)
    radius = len(taps) // 2
    for axis in (-2, -1):
        size = maps.shape[axis]
        pad = [(0, 0)] * maps.ndim
        pad[axis] = (radius, radius)
        padded = jnp.pad(maps, pad, mode="edge")
        maps = sum(float(t) * jax.lax.slice_in_dim(padded, i, i + size, axis=axis % maps.ndim)
                   for i, t in enumerate(taps))
    return maps


@functools.partial(jax.jit, static_argnames=("width_scale", "quality_sigma", "angle_sigma", "width_sigma"))
def predict_grasps(maps: GraspMaps, width_scale: float = WIDTH_SCALE, quality_sigma: float = QUALITY_SIGMA,
                   angle_sigma: float = ANGLE_SIGMA, width_sigma: float = WIDTH_SIGMA):
    """(grasps [B, 5] (x, y, w, h, theta) in view pixels, the smoothed quality at each peak [B])."""
    quality = gaussian_blur(maps.quality.astype(jnp.float32), quality_sigma)
    cos = gaussian_blur(maps.cos.astype(jnp.float32), angle_sigma)
    sin = gaussian_blur(maps.sin.astype(jnp.float32), angle_sigma)
    width = gaussian_blur(maps.width.astype(jnp.float32), width_sigma)
    batch, height, columns = quality.shape
    peak = jnp.argmax(quality.reshape(batch, -1), axis=-1)

    def at_peak(image):
        return jnp.take_along_axis(image.reshape(batch, -1), peak[:, None], axis=-1)[:, 0]

    theta = geometry.normalize_angle(0.5 * jnp.arctan2(at_peak(sin), at_peak(cos)))
    opening = at_peak(width) * width_scale
    x = (peak % columns).astype(jnp.float32) + 0.5
    y = (peak // columns).astype(jnp.float32) + 0.5
    return jnp.stack([x, y, opening, opening / 2, theta], axis=-1), at_peak(quality)

