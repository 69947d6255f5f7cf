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



def _clamp_outline(xs, ys, lo, hi):
    """Clamp the xs of a closed outline to [lo, hi]: lists of n arrays -> lists of 3n arrays.

    Each edge yields its clamped start and its clamped crossings of lo and hi in the order the edge
    meets them (a crossing beyond the edge lands on an end). The vertices stay separate arrays, so
    XLA fuses the whole computation into elementwise loops over the batch.
    """
    out_x, out_y = [], []
    for i in range(len(xs)):
        x0, y0, x1, y1 = xs[i], ys[i], xs[(i + 1) % len(xs)], ys[(i + 1) % len(xs)]
        step, rise = x1 - x0, y1 - y0
        flat = step == 0
        safe_step = jnp.where(flat, 1.0, step)
        t_lo = jnp.where(flat, 0.0, jnp.clip((lo - x0) / safe_step, 0.0, 1.0))
        t_hi = jnp.where(flat, 0.0, jnp.clip((hi - x0) / safe_step, 0.0, 1.0))
        for t in (None, jnp.minimum(t_lo, t_hi), jnp.maximum(t_lo, t_hi)):
            out_x.append(jnp.clip(x0 if t is None else x0 + t * step, lo, hi))
            out_y.append(y0 if t is None else y0 + t * rise)
    return out_x, out_y


def _shoelace(xs, ys):
    n = len(xs)
    return 0.5 * sum(xs[i] * ys[(i + 1) % n] - xs[(i + 1) % n] * ys[i] for i in range(n))


def intersection_area(a, b):
    """Area of the intersection of rotated rectangles a, b: [..., 5] arrays, or 5-tuples of arrays."""
    # A's corners in B's frame (axes u = (cos, -sin), v = (sin, cos) of B's angle)
    cos_b, sin_b = jnp.cos(b[4]), jnp.sin(b[4])
    dx, dy = a[0] - b[0], a[1] - b[1]
    centre_x, centre_y = dx * cos_b - dy * sin_b, dx * sin_b + dy * cos_b
    turn = a[4] - b[4]
    cos_t, sin_t = jnp.cos(turn), jnp.sin(turn)
    half_w, half_h = a[2] / 2, a[3] / 2
    xs, ys = [], []
    for along, across in ((-1, -1), (1, -1), (1, 1), (-1, 1)):  # p0..p3 of grasps_to_corners
        xs.append(centre_x + along * half_w * cos_t + across * half_h * sin_t)
        ys.append(centre_y - along * half_w * sin_t + across * half_h * cos_t)
    box_w, box_h = b[2] / 2, b[3] / 2
    xs, ys = _clamp_outline(xs, ys, -box_w, box_w)
    ys, xs = _clamp_outline(ys, xs, -box_h, box_h)
    return jnp.abs(_shoelace(xs, ys))


def unstack(rects):
    """[..., 5] array -> tuple of its five fields; a tuple passes through."""
    return rects if isinstance(rects, tuple) else tuple(rects[..., k] for k in range(5))


def exact_iou(a, b):
    """Exact IoU of rotated rectangles [..., 5] (x, y, w, h, theta), or 5-tuples of arrays that
    broadcast; 0 when the union is empty."""
    a, b = unstack(a), unstack(b)
    inter = intersection_area(a, b)
    union = jnp.abs(a[2] * a[3]) + jnp.abs(b[2] * b[3]) - inter
    return jnp.where(union > 0, inter / jnp.where(union > 0, union, 1.0), 0.0)
