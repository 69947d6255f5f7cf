"""Position words: the 3 x 3 grid of the paper (section II) and the quadrants of a mosaic.

The words are those of the KOSMOS-E code: rows top / middle / bottom, columns left / middle /
right, the centre cell "center", e.g. "top left", "top middle", "middle right", "bottom middle".
A point (x, y) (pixel-corner origin, DESIGN section 2) lies in column floor(3 x / width) and row
floor(3 y / height), clipped to [0, 2]. (The KOSMOS-E code divides by width // 3 = 74, which leaves
the last two pixel columns of a 224 image without a word; we use exact thirds.)
"""

from __future__ import annotations

import numpy as np

GRID_WORDS = (
    ("top left", "top middle", "top right"),
    ("middle left", "center", "middle right"),
    ("bottom left", "bottom middle", "bottom right"),
)
QUADRANT_WORDS = ("top left", "top right", "bottom left", "bottom right")


def grid_cell(point, width: int, height: int) -> tuple[int, int]:
    """(row, column) of the 3 x 3 cell holding the point (x, y)."""
    x, y = float(point[0]), float(point[1])
    if not (np.isfinite(x) and np.isfinite(y)):
        raise ValueError(f"position of a non-finite point ({x}, {y})")
    column = int(np.clip(np.floor(3.0 * x / width), 0, 2))
    row = int(np.clip(np.floor(3.0 * y / height), 0, 2))
    return row, column


def grasps_centroid(grasps) -> np.ndarray:
    """Mean of the grasp centres (equal to the mean of all their corners, as the paper's code uses)."""
    grasps = np.asarray(grasps, np.float64)
    if grasps.ndim != 2 or grasps.shape[0] == 0 or grasps.shape[1] != 5:
        raise ValueError(f"position needs at least one grasp [N, 5], got shape {grasps.shape}")
    return grasps[:, :2].mean(axis=0)


def grid_word(point, width: int, height: int) -> str:
    row, column = grid_cell(point, width, height)
    return GRID_WORDS[row][column]


def position_word(grasps, width: int, height: int) -> str:
    """The 3 x 3 grid word of the grasps' centroid in a width x height image."""
    return grid_word(grasps_centroid(grasps), width, height)


def quadrant_word(quadrant: int) -> str:
    """Mosaic quadrant 0..3 (top left, top right, bottom left, bottom right) as words."""
    if quadrant not in range(4):
        raise ValueError(f"mosaic quadrant must be 0..3, got {quadrant!r}")
    return QUADRANT_WORDS[quadrant]
