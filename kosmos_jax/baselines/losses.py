"""The published losses of the generative grasp networks, per image, so a batch can be split.

GG-CNN / GG-CNN2: mean squared error on each of the four maps; GR-ConvNet: smooth L1 (Huber with
beta 1) on each map; the loss is the sum of the four map losses, each a mean over pixels. The mean of
`per_image` over a batch is exactly the published batch loss (every image has the same pixel count),
so a trainer adds `per_image` over its microbatches and divides once by the image count.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from kosmos_jax.baselines.layers import GraspMaps

KINDS = ("mse", "smooth_l1")
NETWORK_LOSS = {"ggcnn2": "mse", "grconvnet": "smooth_l1"}


def smooth_l1(difference: jax.Array, beta: float = 1.0) -> jax.Array:
    """0.5 d^2 / beta where |d| < beta, else |d| - 0.5 beta (PyTorch's smooth_l1_loss, elementwise)."""
    size = jnp.abs(difference)
    return jnp.where(size < beta, 0.5 * difference**2 / beta, size - 0.5 * beta)


def map_losses(predicted: GraspMaps, target: GraspMaps, kind: str) -> GraspMaps:
    """Each map's loss per image: GraspMaps of [B] (mean over each image's pixels)."""
    if kind not in KINDS:
        raise ValueError(f"loss kind {kind!r} must be one of {KINDS}")
    elementwise = jnp.square if kind == "mse" else smooth_l1

    def one(p, t):
        return jnp.mean(elementwise(p.astype(jnp.float32) - t.astype(jnp.float32)), axis=(-2, -1))

    return GraspMaps(*(one(p, t) for p, t in zip(predicted, target)))


def per_image(predicted: GraspMaps, target: GraspMaps, kind: str) -> jax.Array:
    """[B]: the sum of the four map losses of each image."""
    return sum(map_losses(predicted, target, kind))
