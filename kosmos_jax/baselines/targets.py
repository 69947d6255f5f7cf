"""Training targets of the generative grasp networks, drawn from ground-truth rectangles (GG-CNN,
GR-ConvNet), vectorised and jit-able.

    maps = grasp_maps(grasps, mask, size=224)      # grasps [B, N, 5], mask [B, N] -> GraspMaps [B, H, W]

Each rectangle (x, y, w, h, theta) (kosmos_jax.geometry's convention) is drawn shrunk to its centre
third along the opening axis (w / 3 long, the full jaw size h across), as the papers draw their
"compact" rectangles. A pixel belongs to a rectangle when its CENTRE (column + 0.5, row + 0.5) lies
inside it, edges included. Inside, the maps hold
  quality 1,  cos 2 theta,  sin 2 theta,  width min(w, 150) / 150   (WIDTH_SCALE: GG-CNN's 150 px);
outside every rectangle quality and width are 0 and the angle is 0, so cos 2 theta is 1 and sin 2
theta 0 there: the published targets' background, kept. Where rectangles overlap, the one listed
last wins (the papers draw them in file order, each over the ones before).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from kosmos_jax import geometry
from kosmos_jax.baselines.layers import GraspMaps

WIDTH_SCALE = 150.0  # pixels of opening that map to width 1 (GG-CNN's and GR-ConvNet's scale)
CENTRE_FRACTION = 1.0 / 3.0  # the drawn part of each rectangle's opening


def _size(size) -> tuple[int, int]:
    return (int(size), int(size)) if isinstance(size, int) else (int(size[0]), int(size[1]))


def covering_index(grasps, mask, size, fraction: float = CENTRE_FRACTION):
    """[B, H, W] int32: the index of the last rectangle whose centre part covers each pixel, -1 if none."""
    height, width = _size(size)
    grasps = grasps.astype(jnp.float32)
    cx, cy, opening, jaw, theta = (grasps[..., i, None, None] for i in range(5))  # [B, N, 1, 1]
    u, v = geometry.grasp_axes(theta)  # [B, N, 1, 1, 2]: along the opening, along the jaws
    dx = jnp.arange(width, dtype=jnp.float32) + 0.5 - cx  # [B, N, 1, W]
    dy = jnp.arange(height, dtype=jnp.float32)[:, None] + 0.5 - cy  # [B, N, H, 1]
    along = dx * u[..., 0] + dy * u[..., 1]
    across = dx * v[..., 0] + dy * v[..., 1]
    inside = (jnp.abs(along) <= opening * (fraction / 2)) & (jnp.abs(across) <= jaw / 2)
    inside &= mask[..., None, None]
    order = jnp.arange(grasps.shape[-2], dtype=jnp.int32)[:, None, None]
    return jnp.max(jnp.where(inside, order, -1), axis=-3, initial=-1)


@functools.partial(jax.jit, static_argnames=("size", "width_scale", "fraction"))
def grasp_maps(grasps, mask, size=224, width_scale: float = WIDTH_SCALE,
               fraction: float = CENTRE_FRACTION) -> GraspMaps:
    """The four target maps of a batch: grasps [B, N, 5] in view pixels, mask [B, N] bool; size an
    int or (H, W). Returns GraspMaps of [B, H, W] float32."""
    if grasps.ndim != 3 or grasps.shape[-1] != 5 or mask.shape != grasps.shape[:2]:
        raise ValueError(f"grasps must be [B, N, 5] with mask [B, N]; got {grasps.shape} and {mask.shape}")
    index = covering_index(grasps, mask.astype(bool), size, fraction)
    batch, height, width = index.shape
    hit = index >= 0
    flat = jnp.maximum(index, 0).reshape(batch, height * width)

    def at_pixels(values):  # [B, N] -> [B, H, W], 0 where no rectangle
        picked = jnp.take_along_axis(values.astype(jnp.float32), flat, axis=1).reshape(batch, height, width)
        return jnp.where(hit, picked, 0.0)

    angle = at_pixels(grasps[..., 4])
    opening = jnp.clip(at_pixels(grasps[..., 2]), 0.0, width_scale) / width_scale
    return GraspMaps(hit.astype(jnp.float32), jnp.cos(2 * angle), jnp.sin(2 * angle), opening)
