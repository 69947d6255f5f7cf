"""models.preprocess.pixels: CLIP's rescale and normalisation, and PIL's bicubic resize."""

import jax
import numpy as np
import pytest
from PIL import Image

from kosmos_jax.models.preprocess import CLIP_MEAN, CLIP_STD, pixels


def _images(batch=2, size=224, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (batch, size, size, 3), np.uint8)


def _normalise(x):
    return (x - np.array(CLIP_MEAN, np.float32)) / np.array(CLIP_STD, np.float32)


def test_stored_size_is_rescaled_and_normalised_only():
    images = _images()
    expected = _normalise(images.astype(np.float32) / 255.0)
    got = jax.jit(pixels, static_argnums=1)(images, 224)
    assert got.dtype == np.float32 and got.shape == images.shape
    np.testing.assert_allclose(np.asarray(got), expected, rtol=1e-6, atol=1e-6)


def test_other_model_size_is_resized_as_pil_bicubic():
    images = _images(batch=1)
    x = images[0].astype(np.float32) / 255.0
    resized = np.stack([np.asarray(Image.fromarray(x[..., c], mode="F").resize((32, 32), Image.BICUBIC))
                        for c in range(3)], axis=-1)
    got = np.asarray(pixels(images, 32))
    assert got.shape == (1, 32, 32, 3)
    np.testing.assert_allclose(got[0], _normalise(resized), atol=1e-5)


def test_refuses_float_and_non_square_images():
    with pytest.raises(TypeError, match="uint8"):
        pixels(np.zeros((1, 224, 224, 3), np.float32), 224)
    with pytest.raises(ValueError, match="square"):
        pixels(np.zeros((1, 224, 200, 3), np.uint8), 224)
