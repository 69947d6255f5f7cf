"""Augmentation as pure jit-compiled functions over batches, driven by PRNG keys.

affine.py: the per-sample affine of crop -> rotate -> translate -> crop; warp.py: bilinear
warping of a batch by affines (cv2-compatible, pixel-corner coordinates); pipeline.py: the
recipe (`augment`, `AugmentConfig`, `PAPER_RECIPE`) moving images and grasps together.
"""

from kosmos_jax.augment.pipeline import (
    PAPER_RECIPE,
    AugmentConfig,
    AugmentedBatch,
    augment,
    kept_grasps,
    move_grasps,
    pad_grasps,
)
from kosmos_jax.augment.warp import to_pixel_index_matrix, warp_images

__all__ = [
    "PAPER_RECIPE", "AugmentConfig", "AugmentedBatch", "augment", "kept_grasps", "move_grasps",
    "pad_grasps", "to_pixel_index_matrix", "warp_images",
]
