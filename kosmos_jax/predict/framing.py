"""A caller's photo -> the model's 224 x 224 view, and grasps between the two pixel frames.

The views a run is tested on are crops of photos at their own scale (Cornell's and the synthetic
scenes' photos are 640 x 480): the honest protocol's test crop (dataset.views.HONEST_TEST_CROP)
takes the 351 window at the photo's centre and keeps its central 224. A photo of another size is
first resized so that its shorter side is PHOTO_SHORT_SIDE, the scale the model was trained at,
then cropped the same way; a 640 x 480 photo is not resized and gets exactly its test view. The
paper protocol's test crop is centred on the ground truth, which a new photo does not have, so
prediction uses the image-centre crop under either protocol.

`Framing.matrix` is the whole map, photo pixels -> view pixels (pixel-corner coordinates,
DESIGN.md section 2): the resize's scale, then the crop's affine (augment.affine.recipe_matrix
with no rotation or shift). A grasp read in the view goes back to the photo through its inverse.
"""

from __future__ import annotations

import dataclasses

import cv2
import jax
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.augment import affine
from kosmos_jax.augment.pipeline import AugmentConfig
from kosmos_jax.augment.warp import to_pixel_index_matrix
from kosmos_jax.dataset.views import HONEST_TEST_CROP

PHOTO_SHORT_SIDE = 480
_BORDERS = {"reflect": cv2.BORDER_REFLECT, "constant": cv2.BORDER_CONSTANT}


def _as_3x3(matrix: np.ndarray) -> np.ndarray:
    return np.vstack([matrix, [0.0, 0.0, 1.0]])


@dataclasses.dataclass(frozen=True)
class Framing:
    """How one photo became the model's view: `matrix` [2, 3] maps photo pixels to view pixels."""

    matrix: np.ndarray
    view_size: int

    def to_view(self, grasps) -> np.ndarray:
        """[..., 5] grasps in photo pixels -> view pixels."""
        return _moved(grasps, self.matrix)

    def to_photo(self, grasps) -> np.ndarray:
        """[..., 5] grasps in view pixels -> the caller's photo pixels."""
        return _moved(grasps, np.linalg.inv(_as_3x3(self.matrix))[:2])


def _moved(grasps, matrix) -> np.ndarray:
    grasps = np.asarray(grasps, np.float64)
    flat = grasps.reshape(-1, 5)
    return np.asarray(geometry.transform_grasps(flat, matrix)).reshape(grasps.shape)


def scale_matrix(sx: float, sy: float) -> np.ndarray:
    return np.array([[sx, 0.0, 0.0], [0.0, sy, 0.0]])


def crop_matrix(height: int, width: int, crop: AugmentConfig) -> np.ndarray:
    """The test crop's affine [2, 3] of a photo of this size (no rotation, no shift)."""
    if crop.centre_policy != "image_centre":
        raise ValueError(f"a photo without labels is cropped at its centre, not by {crop.centre_policy!r}")
    no_grasp, no_mask = np.zeros((1, 5), np.float32), np.zeros(1, bool)
    corner = affine.crop_corner(jax.random.key(0), no_grasp, no_mask, (height, width), crop.crop_size,
                                crop.centre_policy, crop.integer_steps)
    matrix = affine.recipe_matrix(corner, np.float32(0.0), np.zeros(2, np.float32), crop.crop_size, crop.output_size)
    return np.asarray(matrix, np.float64)


def frame(photo: np.ndarray, short_side: int = PHOTO_SHORT_SIDE,
          crop: AugmentConfig = HONEST_TEST_CROP) -> tuple[np.ndarray, Framing]:
    """(the view [S, S, 3] uint8, its Framing) of an [H, W, 3] uint8 photo."""
    height, width = photo.shape[:2]
    factor = short_side / min(height, width)
    new_w, new_h = max(1, round(width * factor)), max(1, round(height * factor))
    if (new_w, new_h) != (width, height):
        # INTER_AREA averages when shrinking (no aliasing); cubic when enlarging
        method = cv2.INTER_AREA if factor < 1 else cv2.INTER_CUBIC
        photo = cv2.resize(photo, (new_w, new_h), interpolation=method)
    cropping = crop_matrix(new_h, new_w, crop)
    size = crop.output_size
    view = cv2.warpAffine(photo, to_pixel_index_matrix(cropping), (size, size), flags=cv2.INTER_LINEAR,
                          borderMode=_BORDERS[crop.border])
    whole = (_as_3x3(cropping) @ _as_3x3(scale_matrix(new_w / width, new_h / height)))[:2]
    return view, Framing(whole, size)
