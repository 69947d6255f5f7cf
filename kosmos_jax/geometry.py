"""Grasp geometry: the one owner of the conventions of DESIGN.md section 2.

Image axes: x to the right (column), y down (row), origin at the top-left pixel's corner.
A grasp is (x, y, w, h, theta): centre, opening w = |p1 - p0| (the axis along which the gripper
closes), jaw size h = |p2 - p1|, theta = the angle of p0 -> p1, in [-pi/2, pi/2), positive
anticlockwise on screen (so a positive theta points the opening axis up and to the right).

Every function works on numpy arrays (keeping their float64 precision) and on jax arrays,
including inside jit; batch dimensions broadcast.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

ANGLE_BINS = 256


def array_module(*arrays):
    """jax.numpy if any argument is a jax array or tracer, else numpy."""
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


def normalize_angle(theta):
    """Map any angle to the grasp range [-pi/2, pi/2) (a grasp is symmetric under a half turn)."""
    xp = array_module(theta)
    return xp.mod(theta + math.pi / 2, math.pi) - math.pi / 2


def angle_difference(a, b):
    """Absolute angle between two grasp axes, modulo pi, in [0, pi/2]."""
    xp = array_module(a, b)
    return xp.abs(normalize_angle(a - b))


def encode_angle(theta):
    """KOSMOS-E's 256-bin angle code: k = clip(round((theta + pi/2) / pi * 256), 0, 255)."""
    xp = array_module(theta)
    k = xp.round((normalize_angle(theta) + math.pi / 2) / math.pi * ANGLE_BINS)
    return xp.clip(k, 0, ANGLE_BINS - 1).astype(xp.int32)


def decode_angle(code):
    """Inverse of `encode_angle`: theta = k / 256 * pi - pi/2."""
    xp = array_module(code)
    return code / ANGLE_BINS * math.pi - math.pi / 2 if xp is jnp else np.asarray(code, np.float64) / ANGLE_BINS * math.pi - math.pi / 2


def corners_to_grasps(corners):
    """[..., 4, 2] corners (x, y) in file order p0..p3 -> [..., 5] (x, y, w, h, theta)."""
    xp = array_module(corners)
    p0, p1, p2 = corners[..., 0, :], corners[..., 1, :], corners[..., 2, :]
    centre = corners.mean(axis=-2)
    opening = p1 - p0
    w = xp.hypot(opening[..., 0], opening[..., 1])
    jaw = p2 - p1
    h = xp.hypot(jaw[..., 0], jaw[..., 1])
    theta = normalize_angle(xp.arctan2(-opening[..., 1], opening[..., 0]))
    return xp.stack([centre[..., 0], centre[..., 1], w, h, theta], axis=-1)


def grasp_axes(theta):
    """Unit vectors (u along the opening, v along the jaws) in image coordinates, [..., 2] each."""
    xp = array_module(theta)
    cos, sin = xp.cos(theta), xp.sin(theta)
    u = xp.stack([cos, -sin], axis=-1)  # y points down, so anticlockwise on screen is -y
    v = xp.stack([sin, cos], axis=-1)
    return u, v


def grasps_to_corners(grasps):
    """[..., 5] (x, y, w, h, theta) -> [..., 4, 2] corners p0..p3 with p0 -> p1 the opening."""
    xp = array_module(grasps)
    centre = grasps[..., 0:2]
    half_w = grasps[..., 2:3] / 2
    half_h = grasps[..., 3:4] / 2
    u, v = grasp_axes(grasps[..., 4])
    p0 = centre - half_w * u - half_h * v
    p1 = centre + half_w * u - half_h * v
    p2 = centre + half_w * u + half_h * v
    p3 = centre - half_w * u + half_h * v
    return xp.stack([p0, p1, p2, p3], axis=-2)


def transform_points(points, matrix):
    """Apply a [..., 2, 3] (or [..., 3, 3]) affine matrix to [..., P, 2] points (x, y)."""
    xp = array_module(points, matrix)
    linear = matrix[..., :2, :2]
    offset = matrix[..., :2, 2]
    return xp.einsum("...ij,...pj->...pi", linear, points) + offset[..., None, :]


def transform_grasps(grasps, matrix):
    """Move [..., N, 5] grasps by a [..., 2, 3] affine matrix (rotation, uniform scale, shift).

    The corners are transformed and re-measured, so w, h scale and theta turns with the image.
    """
    corners = grasps_to_corners(grasps)  # [..., N, 4, 2]
    shape = corners.shape
    flat = corners.reshape(shape[:-3] + (shape[-3] * 4, 2))
    moved = transform_points(flat, matrix).reshape(shape)
    return corners_to_grasps(moved)


def rotation_matrix(angle_rad, centre):
    """2x3 matrix rotating the image content by `angle_rad` anticlockwise on screen about `centre`.

    Same convention as cv2.getRotationMatrix2D(centre, degrees(angle), 1.0).
    """
    xp = array_module(angle_rad, centre)
    cos, sin = xp.cos(angle_rad), xp.sin(angle_rad)
    cx, cy = centre[..., 0], centre[..., 1]
    row0 = xp.stack([cos, sin, (1 - cos) * cx - sin * cy], axis=-1)
    row1 = xp.stack([-sin, cos, sin * cx + (1 - cos) * cy], axis=-1)
    return xp.stack([row0, row1], axis=-2)


def translation_matrix(dx, dy):
    """2x3 matrix shifting by (dx, dy) pixels."""
    xp = array_module(dx, dy)
    one, zero = xp.ones_like(dx), xp.zeros_like(dx)
    return xp.stack([xp.stack([one, zero, dx], -1), xp.stack([zero, one, dy], -1)], axis=-2)


def compose(second, first):
    """The 2x3 affine that applies `first` then `second`."""
    xp = array_module(second, first)
    # zeros_like keeps the input's sharding (an Explicit mesh refuses an unsharded operand)
    bottom = xp.zeros_like(first[..., :1, :]) + xp.asarray([0.0, 0.0, 1.0], first.dtype)
    first3 = xp.concatenate([first, bottom], axis=-2)
    return xp.einsum("...ij,...jk->...ik", second, first3)
