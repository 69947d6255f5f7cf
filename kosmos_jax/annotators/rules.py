"""Rule-based words from pixels: the object's colour names and its position from the grasps.

Colour: the region examined is the whole image or, when grasps are given, the box around all
grasp corners enlarged by `grasp_margin` of its size on each side (so other things in a wide
photo stay out). The background is estimated from the region's border (a frame `border` pixels
wide); a pixel belongs to the object when its CIE Lab distance to the border's median colour
exceeds both `min_delta` and the border's own 99th-percentile spread plus `margin` (so a textured
background is not mistaken for the object). Each object pixel takes the
nearest name of a small palette in Lab space; the names that cover at least `min_share` of the
object pixels (at most `max_names`, most frequent first) form the phrase: "black", "blue and
white", "green, yellow, and silver" (the style of the KOSMOS-E annotations). When no name reaches
`min_share` (a many-coloured object), the most frequent name stands for it, so the phrase is never
empty. When no pixel differs from the background the colour cannot be named: `NoColourError`.

Limits: a white or light grey object on a light table differs little from it and may be missed;
shadows are damped (lightness counts half) but not removed. On the 100 real Cornell photos of
../shared/data the first rule name is one of the KOSMOS-E colour words for 43 of them.

Position: the 3 x 3 grid word of the grasps' centroid (`kosmos_jax.instruct.position`).
"""

from __future__ import annotations

import cv2
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.annotators.base import ObjectWords
from kosmos_jax.annotators.position import position_word

# sRGB anchors of the palette; the names are colour words of the KOSMOS-E annotation file.
PALETTE = {
    "black": (20, 20, 20),
    "gray": (128, 128, 128),
    "silver": (192, 192, 192),
    "white": (245, 245, 245),
    "red": (200, 30, 30),
    "orange": (245, 130, 20),
    "yellow": (240, 220, 40),
    "green": (40, 150, 60),
    "blue": (40, 80, 200),
    "purple": (120, 50, 160),
    "pink": (240, 130, 180),
    "brown": (120, 75, 40),
    "beige": (225, 205, 165),
}


class NoColourError(ValueError):
    """The photo's pixels give no colour (nothing differs from the background, or the region is too
    small to estimate it); the photo has no colour words, its other words are unaffected."""


def rgb_to_lab(rgb) -> np.ndarray:
    """[..., 3] uint8 or [0, 1] float sRGB -> [..., 3] float32 CIE Lab (L in [0, 100])."""
    rgb = np.asarray(rgb)
    scaled = rgb.astype(np.float32) / 255.0 if rgb.dtype == np.uint8 else rgb.astype(np.float32)
    flat = scaled.reshape(-1, 1, 3)
    return cv2.cvtColor(flat, cv2.COLOR_RGB2Lab).reshape(rgb.shape[:-1] + (3,))


_PALETTE_NAMES = tuple(PALETTE)
_PALETTE_LAB = rgb_to_lab(np.array([PALETTE[n] for n in _PALETTE_NAMES], np.uint8))


def nearest_colour_names(lab: np.ndarray) -> np.ndarray:
    """[N, 3] Lab -> [N] indices into the palette's names."""
    distances = np.linalg.norm(lab[:, None, :] - _PALETTE_LAB[None, :, :], axis=-1)
    return distances.argmin(axis=1)


def _roi_box(shape: tuple[int, int], grasps, grasp_margin: float) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1): the whole image, or the box around all grasp corners enlarged by the margin."""
    height, width = shape
    if grasps is None or len(grasps) == 0:
        return 0, 0, width, height
    corners = np.asarray(geometry.grasps_to_corners(np.asarray(grasps, np.float64))).reshape(-1, 2)
    low, high = corners.min(axis=0), corners.max(axis=0)
    pad = (high - low) * grasp_margin
    x0, y0 = np.floor(np.maximum(low - pad, 0)).astype(int)
    x1, y1 = np.ceil(np.minimum(high + pad, [width, height])).astype(int)
    return int(x0), int(y0), int(x1), int(y1)


def object_mask(image, grasps=None, border: int = 6, min_delta: float = 15.0, margin: float = 5.0,
                grasp_margin: float = 0.5, lightness_weight: float = 0.5) -> np.ndarray:
    """[H, W] bool: the pixels of the region (whole image, or the grasp box) that differ from its border."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"colour annotation needs an [H, W, 3] RGB image, got shape {image.shape}")
    x0, y0, x1, y1 = _roi_box(image.shape[:2], grasps, grasp_margin)
    if min(x1 - x0, y1 - y0) <= 2 * border:
        raise NoColourError(f"region {x1 - x0} x {y1 - y0} too small for a {border}-pixel background border")
    lab = rgb_to_lab(image[y0:y1, x0:x1])
    frame = np.ones(lab.shape[:2], bool)
    frame[border:-border, border:-border] = False
    background = np.median(lab[frame], axis=0)
    # Shadows differ from the table mostly in lightness, so lightness counts less than hue.
    difference = (lab - background) * np.array([lightness_weight, 1.0, 1.0], np.float32)
    distance = np.linalg.norm(difference, axis=-1)
    threshold = max(min_delta, float(np.quantile(distance[frame], 0.99)) + margin)
    mask = np.zeros(image.shape[:2], bool)
    mask[y0:y1, x0:x1] = distance > threshold
    return mask


def colour_phrase(names: list[str]) -> str:
    if len(names) <= 2:
        return " and ".join(names)
    return ", ".join(names[:-1]) + ", and " + names[-1]


def colour_names(image, grasps=None, min_share: float = 0.2, max_names: int = 3, **mask_options) -> list[str]:
    """The palette names of the object's pixels, most frequent first; never empty."""
    if max_names < 1:
        raise ValueError(f"max_names must be at least 1, got {max_names}")
    mask = object_mask(image, grasps, **mask_options)
    if not mask.any():
        raise NoColourError("no pixel differs from the background; cannot name the object's colour")
    lab = rgb_to_lab(np.asarray(image))[mask]
    counts = np.bincount(nearest_colour_names(lab), minlength=len(_PALETTE_NAMES))
    shares = counts / counts.sum()
    order = [int(i) for i in np.argsort(-shares, kind="stable")]
    chosen = [i for i in order if shares[i] >= min_share][:max_names]
    return [_PALETTE_NAMES[i] for i in (chosen or order[:1])]


def words_from_pixels(image, grasps=None, **options) -> ObjectWords:
    """ObjectWords with the colour computed from pixels (the other kinds need another annotator)."""
    return ObjectWords(colour=colour_phrase(colour_names(image, grasps, **options)))


def position_from_grasps(grasps, width: int, height: int) -> str:
    """The 3 x 3 grid word of the grasps' centroid."""
    return position_word(grasps, width, height)
