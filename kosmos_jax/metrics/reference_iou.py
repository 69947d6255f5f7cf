"""IoU by counting integer pixel centres, as the public GG-CNN / GR-ConvNet / KOSMOS-E code does.

That code rasterises both rectangles with skimage.draw.polygon (rows = y, columns = x) and compares
pixel sets. skimage (0.16 and later, O'Rourke's test) keeps a pixel (r, c) when it lies inside the
polygon or on its boundary. For a convex polygon that is c in [x_left, x_right] on each row r, which
we count in closed form per row instead of testing pixels. skimage also starts its scan at row and
column 0, so pixels at negative rows or columns are dropped: that quirk is kept, because it changes
their published numbers near the image border. (skimage before 0.16 used a half-open rule; the
difference is only pixels exactly on an edge.)
"""

from __future__ import annotations

import jax.numpy as jnp

from kosmos_jax import geometry


def _row_spans(corners, rows):
    """Closed span [left, right] of each row [..., K] across a convex polygon [..., 4, 2].

    +inf / -inf where the row misses the polygon.
    """
    x_i, y_i = corners[..., 0], corners[..., 1]
    x_j, y_j = jnp.roll(x_i, 1, axis=-1), jnp.roll(y_i, 1, axis=-1)
    r = rows[..., :, None]  # [..., K, 1] against edges [..., 1, 4]
    y_i, y_j, x_i, x_j = (v[..., None, :] for v in (y_i, y_j, x_i, x_j))
    meets = (jnp.minimum(y_i, y_j) <= r) & (r <= jnp.maximum(y_i, y_j))
    level = y_i == y_j  # a horizontal edge on this row contributes both of its ends
    dy = jnp.where(level, 1.0, y_j - y_i)
    x_cross = x_i + (x_j - x_i) * (r - y_i) / dy
    low = jnp.where(level, jnp.minimum(x_i, x_j), x_cross)
    high = jnp.where(level, jnp.maximum(x_i, x_j), x_cross)
    left = jnp.min(jnp.where(meets, low, jnp.inf), axis=-1)
    right = jnp.max(jnp.where(meets, high, -jnp.inf), axis=-1)
    return left, right


def _count(left, right):
    """Integer columns c >= 0 with left <= c <= right, summed over rows."""
    per_row = jnp.floor(right) - jnp.maximum(jnp.ceil(left), 0.0) + 1
    per_row = jnp.where(jnp.isfinite(per_row), per_row, 0.0)
    return jnp.sum(jnp.maximum(per_row, 0.0), axis=-1)


def _window(corners, max_rows: int):
    """The rows skimage scans for a polygon: from max(0, floor(y_min)), `max_rows` of them."""
    y = corners[..., 1]
    first = jnp.maximum(jnp.floor(jnp.min(y, axis=-1)), 0.0)
    needed = jnp.ceil(jnp.max(y, axis=-1)) - first + 1
    rows = first[..., None] + jnp.arange(max_rows, dtype=corners.dtype)
    return rows, needed <= max_rows


def reference_iou(a, b, max_rows: int = 512):
    """Pixel-count IoU of rotated rectangles [..., 5]; NaN when one spans more than `max_rows` rows."""
    a, b = jnp.broadcast_arrays(jnp.asarray(a), jnp.asarray(b))
    corners_a, corners_b = geometry.grasps_to_corners(a), geometry.grasps_to_corners(b)
    rows_a, fits_a = _window(corners_a, max_rows)
    rows_b, fits_b = _window(corners_b, max_rows)
    left_a, right_a = _row_spans(corners_a, rows_a)
    left_b, right_b = _row_spans(corners_b, rows_b)
    left_ab, right_ab = _row_spans(corners_b, rows_a)
    # A zero-area rectangle holds no pixel (skimage's crossing test is inconsistent on a segment).
    solid_a, solid_b = a[..., 2] * a[..., 3] > 0, b[..., 2] * b[..., 3] > 0
    area_a = jnp.where(solid_a, _count(left_a, right_a), 0.0)
    area_b = jnp.where(solid_b, _count(left_b, right_b), 0.0)
    inter = jnp.where(solid_a & solid_b, _count(jnp.maximum(left_a, left_ab), jnp.minimum(right_a, right_ab)), 0.0)
    union = area_a + area_b - inter
    iou = jnp.where(union > 0, inter / jnp.where(union > 0, union, 1.0), 0.0)
    return jnp.where(fits_a & fits_b, iou, jnp.nan)
