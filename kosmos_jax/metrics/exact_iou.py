"""Exact IoU of rotated rectangles by convex clipping, vectorised and jit-friendly.

B is an axis-aligned box in its own frame, so A ∩ B is A clipped to two slabs. Clamping one
coordinate of a closed outline to [lo, hi] gives an outline whose signed area is exactly the area
of the part of A inside that slab (outside the slab nothing is left; inside it the outline is
unchanged). A clamped edge stays straight between the points where it crosses lo and hi, so each
edge becomes 3 vertices: 4 -> 12 -> 36 vertices, then the shoelace formula. No data-dependent
shapes, no sorting, no masks.
"""

from __future__ import annotations

import jax.numpy as jnp

from kosmos_jax import geometry


def _clamp_outline(points, axis: int, lo, hi):
    """Clamp coordinate `axis` of a closed outline [..., n, 2] to [lo, hi] -> [..., 3n, 2]."""
    start = points
    end = jnp.roll(points, -1, axis=-2)
    a, b = start[..., axis], end[..., axis]
    step = b - a
    flat = step == 0
    safe_step = jnp.where(flat, 1.0, step)
    t_lo = jnp.where(flat, 0.0, jnp.clip((lo[..., None] - a) / safe_step, 0.0, 1.0))
    t_hi = jnp.where(flat, 0.0, jnp.clip((hi[..., None] - a) / safe_step, 0.0, 1.0))
    t_first, t_second = jnp.minimum(t_lo, t_hi), jnp.maximum(t_lo, t_hi)

    def clamped_at(t):
        point = start + t[..., None] * (end - start)
        coord = jnp.clip(point[..., axis], lo[..., None], hi[..., None])
        return point.at[..., axis].set(coord)

    vertices = jnp.stack([clamped_at(jnp.zeros_like(t_first)), clamped_at(t_first), clamped_at(t_second)], axis=-2)
    return vertices.reshape(vertices.shape[:-3] + (-1, 2))


def _shoelace(points):
    x, y = points[..., 0], points[..., 1]
    return 0.5 * jnp.sum(x * jnp.roll(y, -1, axis=-1) - jnp.roll(x, -1, axis=-1) * y, axis=-1)


def intersection_area(a, b):
    """Area of the intersection of rotated rectangles a, b: [..., 5] each (broadcast)."""
    a, b = jnp.broadcast_arrays(a, b)
    u, v = geometry.grasp_axes(b[..., 4])
    relative = geometry.grasps_to_corners(a)[..., :, :] - b[..., None, 0:2]
    local = jnp.stack(
        [jnp.sum(relative * u[..., None, :], axis=-1), jnp.sum(relative * v[..., None, :], axis=-1)], axis=-1
    )
    half_w, half_h = b[..., 2] / 2, b[..., 3] / 2
    outline = _clamp_outline(local, 0, -half_w, half_w)
    outline = _clamp_outline(outline, 1, -half_h, half_h)
    return jnp.abs(_shoelace(outline))


def exact_iou(a, b):
    """Exact IoU of rotated rectangles [..., 5] (x, y, w, h, theta); 0 when the union is empty."""
    a, b = jnp.broadcast_arrays(jnp.asarray(a), jnp.asarray(b))
    inter = intersection_area(a, b)
    union = jnp.abs(a[..., 2] * a[..., 3]) + jnp.abs(b[..., 2] * b[..., 3]) - inter
    return jnp.where(union > 0, inter / jnp.where(union > 0, union, 1.0), 0.0)
