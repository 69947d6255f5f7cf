"""Images as KOSMOS-2's processor hands them to the model: one function for training, evaluation and prediction.

transformers' CLIPImageProcessor (KOSMOS-2's) resizes the shortest edge bicubically, centre-crops,
rescales by 1/255 and normalises with CLIP's mean and std. The stored images are already square at
224, the processor's size, so for the real model this is rescale and normalise only; a model of
another `image_size` (the tiny and demo ones) gets the image resized to it first, bicubic with
antialiasing as PIL resizes (Keys cubic, a = -0.5, kernel widened when shrinking), in float without
PIL's rounding back to uint8.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
STORED_IMAGE_SIZE = 224


def pixels(images: jax.Array, image_size: int) -> jax.Array:
    """uint8 images [..., H, W, 3] -> float32 [..., image_size, image_size, 3], normalised."""
    if images.dtype != jnp.uint8:
        raise TypeError(f"images must be uint8 as stored, got {images.dtype}")
    height, width = images.shape[-3:-1]
    if height != width:
        raise ValueError(f"images must be square as stored, got {height}x{width}")
    x = images.astype(jnp.float32) / 255.0
    if height != image_size:
        shape = (*images.shape[:-3], image_size, image_size, images.shape[-1])
        x = jax.image.resize(x, shape, method="bicubic", antialias=True)
    return (x - jnp.asarray(CLIP_MEAN, jnp.float32)) / jnp.asarray(CLIP_STD, jnp.float32)
