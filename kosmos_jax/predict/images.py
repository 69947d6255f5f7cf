"""A caller's image (a path or an array) -> an H x W x 3 uint8 RGB array, or one clear ImageError.

Read with OpenCV from the file's bytes (so a file that is not an image is told apart from a
missing one). Grey images are repeated to three channels, an alpha channel is dropped (the
colours are kept as they are, not blended over a background) and 16-bit images are scaled to
8 bits (value / 257, rounded); each conversion says so in an ImageWarning.
"""

from __future__ import annotations

import os
import pathlib
import warnings

import cv2
import numpy as np

from kosmos_jax.predict.errors import ImageError, ImageWarning


def read_image_file(path) -> np.ndarray:
    """The pixels of an image file as stored: uint8 or uint16, [H, W] or [H, W, 3 or 4], RGB order."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise ImageError(f"{path}: no such image file")
    data = np.fromfile(path, np.uint8)
    decoded = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if decoded is None:
        raise ImageError(f"{path}: not an image OpenCV can read (PNG, JPEG, TIFF, ...)")
    if decoded.ndim == 3 and decoded.shape[2] == 3:
        return cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)
    if decoded.ndim == 3 and decoded.shape[2] == 4:
        return cv2.cvtColor(decoded, cv2.COLOR_BGRA2RGBA)
    return decoded


def as_rgb8(pixels: np.ndarray, source: str = "image") -> np.ndarray:
    """[H, W, 3] uint8 RGB of grey, RGB or RGBA pixels in uint8 or uint16."""
    pixels = np.asarray(pixels)
    if pixels.dtype == np.uint16:
        warnings.warn(f"{source}: 16-bit image scaled to 8 bits", ImageWarning, stacklevel=3)
        pixels = np.round(pixels / 257.0).astype(np.uint8)
    elif pixels.dtype != np.uint8:
        raise ImageError(f"{source}: pixels of type {pixels.dtype}; give uint8 (or uint16) values, 0..255")
    if pixels.ndim == 3 and pixels.shape[2] == 1:
        pixels = pixels[..., 0]
    if pixels.ndim == 2:
        warnings.warn(f"{source}: grey image converted to RGB", ImageWarning, stacklevel=3)
        pixels = np.repeat(pixels[..., None], 3, axis=2)
    elif pixels.ndim == 3 and pixels.shape[2] == 4:
        warnings.warn(f"{source}: RGBA image, alpha channel dropped", ImageWarning, stacklevel=3)
        pixels = pixels[..., :3]
    if pixels.ndim != 3 or pixels.shape[2] != 3:
        raise ImageError(f"{source}: shape {pixels.shape}; expected H x W x 3 (RGB), H x W (grey) or H x W x 4 (RGBA)")
    if min(pixels.shape[:2]) < 1:
        raise ImageError(f"{source}: empty image of shape {pixels.shape}")
    return np.ascontiguousarray(pixels)


def load_image(image) -> np.ndarray:
    """A path (str or PathLike) or an array -> [H, W, 3] uint8 RGB."""
    if isinstance(image, (str, os.PathLike)):
        return as_rgb8(read_image_file(image), str(image))
    if isinstance(image, np.ndarray) or hasattr(image, "__array__"):
        return as_rgb8(np.asarray(image), "image array")
    raise ImageError(f"an image is a path or an H x W x 3 uint8 array, not {type(image).__name__}")
