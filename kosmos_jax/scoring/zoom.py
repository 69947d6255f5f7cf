"""The mosaic zoom: a multi-object instruction answered a second time, on the quadrant its first answer chose.

A mosaic (instruct.mosaic) tiles four views and halves the result, so each photo reaches the model at
half the scale it was trained on for single photos, and a 14 px patch covers twice the object. The
zoom gives the resolution back without telling the model which photo is meant: the first answer's
centre picks the quadrant (the model's own choice of the named object), that quadrant is enlarged 2x
to a whole view (bilinear: chosen on the validation scenes against cubic, within their noise), the
model is asked NON on it (any grasp of the one object it shows: every multi-object kind's target is
a grasp of the named photo's object), and that answer is mapped back to the mosaic. The scale is
uniform, so the angle is unchanged and a centre (x, y) of the zoomed view lands at
(x / 2 + ox, y / 2 + oy), (ox, oy) the quadrant's corner.

A first answer that did not parse chose no quadrant: its zoomed grasp is NaN, a miss, as the answer was.
The zoom relies on the 2 x 2 layout of INSTRUCT-GRASP's mosaics; it is not a procedure for a photo of
several objects, and the one-pass figures are always reported beside it.
"""

from __future__ import annotations

import cv2
import numpy as np

ZOOM = 2  # a mosaic's quadrant is a view at half scale


def quadrant_corners(centres: np.ndarray, size: int) -> np.ndarray:
    """int [G, 2] (ox, oy) of the quadrant of a `size` x `size` mosaic holding each centre [G, 2]
    (pixel-corner coordinates: x < size / 2 is the left half), -1 where a centre is not finite."""
    centres = np.asarray(centres, np.float64)
    half = size // ZOOM
    corners = np.where(centres >= half, half, 0).astype(np.int64)
    return np.where(np.isfinite(centres).all(axis=-1, keepdims=True), corners, -1)


def zoomed_view(image: np.ndarray, corner) -> np.ndarray:
    """The quadrant of `image` [S, S, C] at `corner` (ox, oy), enlarged to [S, S, C]."""
    size = image.shape[0]
    if image.shape[1] != size or size % ZOOM:
        raise ValueError(f"a mosaic is square with an even side, got {image.shape[:2]}")
    ox, oy = (int(c) for c in corner)
    half = size // ZOOM
    if ox not in (0, half) or oy not in (0, half):
        raise ValueError(f"({ox}, {oy}) is not a quadrant's corner of a {size} px mosaic")
    tile = np.ascontiguousarray(image[oy:oy + half, ox:ox + half])
    view = cv2.resize(tile, (size, size), interpolation=cv2.INTER_LINEAR)
    return view.reshape(size, size, *image.shape[2:])


def from_zoomed(grasps: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """[G, 3] (x, y, theta) answered on zoomed views -> the mosaic's pixels; NaN where corners are -1."""
    grasps = np.asarray(grasps, np.float64)
    corners = np.asarray(corners)
    moved = np.concatenate([grasps[:, :2] / ZOOM + corners, grasps[:, 2:]], axis=1)
    return np.where((corners >= 0).all(axis=1, keepdims=True), moved, np.nan)
