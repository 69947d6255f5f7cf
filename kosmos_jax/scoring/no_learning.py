"""Two predictors that learn nothing. Beside a model they show how much a protocol leaks: a test
view centred on the labels lets the image centre score well without looking at the image."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np


def image_centre(grasps, mask, image_size: int = 224):
    """(x, y, theta) = the centre of the view, angle 0, for every view: [V, 3]."""
    del mask
    count = grasps.shape[0]
    return np.tile(np.array([[image_size / 2, image_size / 2, 0.0]], np.float32), (count, 1))


def mean_axis_angle(theta, weights):
    """Mean of grasp angles, which are axes (theta ~ theta + pi): average the doubled angle."""
    c = jnp.sum(weights * jnp.cos(2 * theta), axis=-1)
    s = jnp.sum(weights * jnp.sin(2 * theta), axis=-1)
    return jnp.arctan2(s, c) / 2


def ground_truth_mean(grasps, mask):
    """Oracle: the mean centre and mean axis of the view's own ground truths: [V, 3] (NaN if none)."""
    grasps, weights = jnp.asarray(grasps), jnp.asarray(mask, jnp.float32)
    count = jnp.sum(weights, axis=-1)
    centre = jnp.sum(grasps[..., :2] * weights[..., None], axis=-2) / count[..., None]
    theta = jnp.where(count > 0, mean_axis_angle(grasps[..., 4], weights), jnp.nan)
    return np.asarray(jnp.concatenate([centre, theta[..., None]], axis=-1))


PREDICTORS = {"image_centre": image_centre, "gt_mean_oracle": ground_truth_mean}
