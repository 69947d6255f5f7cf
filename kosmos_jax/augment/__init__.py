"""Stage 2, augmentation: photos and their grasps in, 224 x 224 views with the grasps moved along out.

Pure jit-compiled functions over batches, driven by PRNG keys: affine.py (crop -> rotate ->
translate -> crop), warp.py (bilinear warping, cv2-compatible), pipeline.py (`augment`, `AugmentConfig`).
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
