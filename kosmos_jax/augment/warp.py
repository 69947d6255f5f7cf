"""Bilinear warping of a batch of images by affine matrices, jit-able, static output size.

Coordinates. A matrix here is a FORWARD map in grasp coordinates (DESIGN.md section 2: x right,
y down, origin at the top-left pixel's CORNER, so pixel (row i, column j) covers [j, j + 1) x
[i, i + 1) and its centre is at (j + 0.5, i + 0.5)). Output pixel (i, j) takes the value of the
source image at A^-1 (j + 0.5, i + 0.5), interpolated bilinearly between source pixel centres.

cv2.warpAffine works on pixel INDICES (pixel centres at integers). The same geometric map in
index coordinates is  A_idx(q) = A(q + 0.5) - 0.5; `to_pixel_index_matrix` returns it, and
cv2.warpAffine(img, to_pixel_index_matrix(A), (w, h), flags=cv2.INTER_LINEAR) samples the same
points as `warp_images(img, A, (h, w))` (up to cv2's 1/32-pixel fixed-point coordinates). For a
rotation, handing cv2 the grasp-coordinate matrix unchanged shifts the image by up to a pixel
against the grasps: the tests check both statements.

Borders. "reflect" mirrors the image about its outer pixel edges (..c b a | a b c ..., i.e.
cv2.BORDER_REFLECT, skimage's mode="symmetric", which GG-CNN-derived code such as KOSMOS-E's
uses for rotations). "constant" fills with zeros (cv2.BORDER_CONSTANT, value 0).

How it is fast on CPU. Both borders are reduced to taps strictly inside the image, so every tap
is a plain in-bounds gather (mode="promise_in_bounds"):
  - reflect: the continuous coordinate is reflected into [-0.5, n - 0.5] (bilinear
    interpolation commutes with the mirror) and clipped to [0, n - 1] (within half a pixel of
    the edge the mirrored neighbour equals the edge pixel, so clipping is exact);
  - constant: taps outside the image get weight 0 and a clamped index (no padded copy of the
    photos, which cost as much as the warp itself).
Then the four taps are gathered from the flattened images with precomputed integer indices
(for reflect idx, idx + 1, idx + W, idx + W + 1) by flat gathers over the whole batch, uint8 stays
uint8 until after the gather, and the weights are float32. (Measured on this 2-core CPU: the
flat gather and the floor/abs reflection instead of jnp.mod each gave ~1.5x over a vmapped
gather and jnp.mod, and dropping the padded copy halved the constant border's time.)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

BORDERS = ("reflect", "constant")


def to_pixel_index_matrix(matrix):
    """Grasp-coordinate (pixel-corner origin) affine [..., 2, 3] -> the same map on pixel indices.

    A_idx(q) = A(q + h) - h with h = (0.5, 0.5): the linear part is unchanged and the offset
    becomes b + L h - h. This is the matrix to hand to cv2.warpAffine.
    """
    xp = jnp if isinstance(matrix, jax.Array) else np
    linear = matrix[..., :2, :2]
    offset = matrix[..., :2, 2] + linear.sum(axis=-1) * 0.5 - 0.5
    return xp.concatenate([linear, offset[..., None]], axis=-1)


def invert_affine(matrix):
    """Inverse of [..., 2, 3] affine matrices (float32 or float64)."""
    a, b, c = matrix[..., 0, 0], matrix[..., 0, 1], matrix[..., 0, 2]
    d, e, f = matrix[..., 1, 0], matrix[..., 1, 1], matrix[..., 1, 2]
    det = a * e - b * d
    ia, ib, id_, ie = e / det, -b / det, -d / det, a / det
    ic = -(ia * c + ib * f)
    if_ = -(id_ * c + ie * f)
    row0 = jnp.stack([ia, ib, ic], axis=-1)
    row1 = jnp.stack([id_, ie, if_], axis=-1)
    return jnp.stack([row0, row1], axis=-2)


def _reflect(coord, size):
    """Mirror a pixel-index coordinate about -0.5 and size - 0.5 (period 2 * size)."""
    period = 2.0 * size
    shifted = coord + 0.5
    folded = shifted - period * jnp.floor(shifted * (1.0 / period))  # in [0, period)
    return (size - jnp.abs(folded - size)) - 0.5


def _source_coordinates(matrices, out_hw):
    """[B, K, 2, 3] forward matrices -> source pixel-index coordinates x, y, each [B, K, h, w]."""
    out_h, out_w = out_hw
    inverse = invert_affine(matrices.astype(jnp.float32))
    # Output pixel centres (j + 0.5, i + 0.5) go through A^-1, then -0.5 to pixel indices.
    cols = jnp.arange(out_w, dtype=jnp.float32) + 0.5
    rows = jnp.arange(out_h, dtype=jnp.float32) + 0.5

    def coordinate(row):  # row: [B, K, 3]
        along_x = row[..., 0, None, None] * cols
        along_y = row[..., 1, None, None] * rows[:, None]
        return along_x + along_y + (row[..., 2] - 0.5)[..., None, None]

    return coordinate(inverse[..., 0, :]), coordinate(inverse[..., 1, :])


def _gather_rows(images):
    """Flattened pixels [B * H * W, C] and each photo's first row, for one flat gather."""
    batch, height, width, channels = images.shape
    flat = images.reshape(batch * height * width, channels)
    photo_start = jnp.arange(batch, dtype=jnp.int32) * (height * width)
    return flat, photo_start[:, None, None, None]


def _bilinear_reflect(images, x, y):
    """Sample [B, H, W, C] at pixel-index coordinates x, y [B, K, h, w], mirrored border."""
    _, height, width, _ = images.shape
    x = jnp.clip(_reflect(x, width), 0.0, width - 1.0)
    y = jnp.clip(_reflect(y, height), 0.0, height - 1.0)
    # The left/top tap stays one short of the last column/row so the right/bottom tap exists
    # (at the last column the right tap then has weight exactly 1). Coordinates are >= 0 here,
    # so the int cast is the floor.
    x0 = jnp.minimum(x.astype(jnp.int32), max(width - 2, 0))
    y0 = jnp.minimum(y.astype(jnp.int32), max(height - 2, 0))
    fx = (x - x0.astype(jnp.float32))[..., None]
    fy = (y - y0.astype(jnp.float32))[..., None]
    step_x = 1 if width > 1 else 0
    step_y = width if height > 1 else 0
    flat, photo_start = _gather_rows(images)
    index = y0 * width + x0 + photo_start

    def tap(offset):
        return flat.at[index + offset].get(mode="promise_in_bounds").astype(jnp.float32)

    top_left = tap(0)
    bottom_left = tap(step_y)
    top = top_left + fx * (tap(step_x) - top_left)
    bottom = bottom_left + fx * (tap(step_y + step_x) - bottom_left)
    return top + fy * (bottom - top)


def _bilinear_constant(images, x, y):
    """Sample [B, H, W, C] at pixel-index coordinates x, y [B, K, h, w], zeros outside.

    Taps outside the image get weight 0 and a clamped (in-bounds) index; coordinates beyond one
    pixel outside read zeros only, so they are clipped to -1 or n first (exact).
    """
    _, height, width, _ = images.shape
    x = jnp.clip(x, -1.0, float(width))
    y = jnp.clip(y, -1.0, float(height))
    x_floor, y_floor = jnp.floor(x), jnp.floor(y)
    fx, fy = (x - x_floor)[..., None], (y - y_floor)[..., None]
    x0, y0 = x_floor.astype(jnp.int32), y_floor.astype(jnp.int32)

    def weights_and_positions(first, frac, size):
        second = first + 1
        w_first = jnp.where(((first >= 0) & (first < size))[..., None], 1.0 - frac, 0.0)
        w_second = jnp.where(((second >= 0) & (second < size))[..., None], frac, 0.0)
        return w_first, w_second, jnp.clip(first, 0, size - 1), jnp.clip(second, 0, size - 1)

    wx0, wx1, cx0, cx1 = weights_and_positions(x0, fx, width)
    wy0, wy1, cy0, cy1 = weights_and_positions(y0, fy, height)
    flat, photo_start = _gather_rows(images)

    def tap(row, col):
        index = row * width + col + photo_start
        return flat.at[index].get(mode="promise_in_bounds").astype(jnp.float32)

    top = wx0 * tap(cy0, cx0) + wx1 * tap(cy0, cx1)
    bottom = wx0 * tap(cy1, cx0) + wx1 * tap(cy1, cx1)
    return wy0 * top + wy1 * bottom


def warp_images(images, matrices, out_hw, border="reflect"):
    """Warp each image by each of its matrices: [B, H, W, C] x [B, K, 2, 3] -> [B, K, h, w, C].

    `matrices` may also be [B, 2, 3] (one warp per image; the result is then [B, h, w, C]).
    uint8 images come back as uint8 (rounded, clipped), float images as their own dtype.
    `out_hw` and `border` are static. Pure and jit-able.
    """
    images = jnp.asarray(images)
    matrices = jnp.asarray(matrices)
    if images.ndim != 4:
        raise ValueError(f"images must be [B, H, W, C], got shape {images.shape}")
    single = matrices.ndim == 3
    if single:
        matrices = matrices[:, None]
    if matrices.ndim != 4 or matrices.shape[-2:] != (2, 3) or matrices.shape[0] != images.shape[0]:
        raise ValueError(
            f"matrices must be [B, K, 2, 3] or [B, 2, 3] with B = {images.shape[0]} (images), "
            f"got shape {matrices.shape}")
    if border not in BORDERS:
        raise ValueError(f"border must be one of {BORDERS}, got {border!r}")
    if images.dtype != jnp.uint8 and not jnp.issubdtype(images.dtype, jnp.floating):
        raise ValueError(f"images must be uint8 or floating point, got dtype {images.dtype}")
    out_h, out_w = (int(v) for v in out_hw)
    if out_h <= 0 or out_w <= 0:
        raise ValueError(f"output size must be positive, got {out_hw}")
    x, y = _source_coordinates(matrices, (out_h, out_w))
    sample = _bilinear_reflect if border == "reflect" else _bilinear_constant
    warped = sample(images, x, y)
    if images.dtype == jnp.uint8:
        warped = jnp.clip(jnp.round(warped), 0, 255).astype(jnp.uint8)
    else:
        warped = warped.astype(images.dtype)
    return warped[:, 0] if single else warped
