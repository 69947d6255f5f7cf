"""The per-sample affine of the recipe crop -> rotate -> translate -> crop, as ONE 2x3 matrix.

All matrices are forward maps (photo point -> output point) in grasp coordinates (pixel-corner
origin, DESIGN.md section 2), built with kosmos_jax.geometry so images and grasps share them:

    A = T(-m, -m) . T(dx, dy) . R(angle about the crop's centre) . T(-left, -top)

where (left, top) is the crop window's corner in the photo, m = (crop - output) // 2 the margin of
the final centre crop (63 for 351 -> 224, as KOSMOS-E's code), and R follows
cv2.getRotationMatrix2D (anticlockwise on screen). Crop windows sit on the pixel grid (integer
left, top), so with angle 0 and integer shifts the whole chain copies pixels exactly.

Centre policies for the first crop (a static setting):
  gt_centroid   the mean of all ground-truth corners (KOSMOS-E's and GG-CNN's code: the crop
                follows the labels, which leaks the answer at test time); a photo with no
                valid grasp falls back to the image centre;
  image_centre  the photo's centre;
  random        a window drawn uniformly among those inside the photo.
The window is then shifted to lie inside the photo when it fits (as KOSMOS-E's
`get_crop_attrs` does); a crop larger than the photo is centred on it.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from kosmos_jax import geometry

CENTRE_POLICIES = ("gt_centroid", "image_centre", "random")


def crop_corner(key, grasps, mask, image_hw, crop_size, policy, integer_centre):
    """Top-left corner (left, top) of the first crop window for one photo, float32 [2].

    grasps [N, 5], mask [N] bool; image_hw, crop_size, policy, integer_centre static.
    integer_centre truncates the centroid to whole pixels first (KOSMOS-E's `.astype(int)`).
    """
    height, width = image_hw
    size = jnp.asarray([width, height], jnp.float32)
    image_centre = size / 2
    if policy == "gt_centroid":
        weights = mask.astype(jnp.float32)
        count = weights.sum()
        # The mean of a rectangle's four corners is its centre, so the corner mean is the mean
        # of the grasp centres.
        centres = jnp.where(mask[:, None], grasps[:, :2].astype(jnp.float32), 0.0)  # padding may be NaN
        total = centres.sum(axis=0)
        centre = jnp.where(count > 0, total / jnp.maximum(count, 1.0), image_centre)
        if integer_centre:
            centre = jnp.floor(centre)
        corner = centre - crop_size // 2 if integer_centre else centre - crop_size / 2
    elif policy == "image_centre":
        corner = image_centre - crop_size / 2
    elif policy == "random":
        room = jnp.maximum(size - crop_size, 0.0)
        corner = jax.random.uniform(key, (2,), jnp.float32) * room
    else:
        raise ValueError(f"centre policy must be one of {CENTRE_POLICIES}, got {policy!r}")
    inside = jnp.clip(corner, 0.0, jnp.maximum(size - crop_size, 0.0))
    fits = size >= crop_size
    corner = jnp.where(fits, inside, (size - crop_size) / 2)
    return jnp.floor(corner + 0.5)  # on the pixel grid


def sample_rotations(key, count, integer_steps):
    """[count] angles in radians in [0, 2 pi); integer_steps: whole degrees 0..359 (KOSMOS-E)."""
    if integer_steps:
        degrees = jax.random.randint(key, (count,), 0, 360)
        return jnp.deg2rad(degrees.astype(jnp.float32))
    return jax.random.uniform(key, (count,), jnp.float32, 0.0, 2 * math.pi)


def sample_translations(key, shape, max_shift, integer_steps):
    """[*shape, 2] shifts (dx, dy) in [-max_shift, max_shift]; integer_steps: whole pixels."""
    if integer_steps:
        limit = int(math.floor(max_shift))
        return jax.random.randint(key, (*shape, 2), -limit, limit + 1).astype(jnp.float32)
    return jax.random.uniform(key, (*shape, 2), jnp.float32, -max_shift, max_shift)


def recipe_matrix(corner, angle, shift, crop_size, output_size):
    """The composed forward affine [..., 2, 3] for crop corner [..., 2], angle [...], shift [..., 2]."""
    corner, angle, shift = jnp.broadcast_arrays(
        corner, jnp.asarray(angle)[..., None], shift)
    angle = angle[..., 0]
    to_crop = geometry.translation_matrix(-corner[..., 0], -corner[..., 1])
    # zeros_like keeps the inputs' sharding (jnp.full would not, which explicit meshes reject)
    crop_centre = jnp.zeros_like(corner) + crop_size / 2
    rotate = geometry.rotation_matrix(angle, crop_centre)
    margin = jnp.zeros_like(angle) + float((crop_size - output_size) // 2)
    shift_then_crop = geometry.translation_matrix(shift[..., 0] - margin, shift[..., 1] - margin)
    return geometry.compose(shift_then_crop, geometry.compose(rotate, to_crop))
