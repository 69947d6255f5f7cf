"""INSTRUCT-GRASP instructions: NON, SINGLE (8 kinds) and MULTI (2 x 2 mosaics, 6 kinds).

Inputs are augmented views (image, grasps in its pixels, the object's words from an annotator);
outputs are `Sample`s (instruction sentence, image, every grasp that answers it, the photo and
object ids inside the image). Formatting to text targets and tokens is a later stage.
"""

from kosmos_jax.instruct.kinds import ALL_KINDS, MULTI_KINDS, NON, SINGLE_KINDS, TEMPLATES, check_kind
from kosmos_jax.instruct.mosaic import build_mosaic, mosaic_image, mosaic_sample
from kosmos_jax.instruct.sample import Sample, View
from kosmos_jax.instruct.single import single_samples

__all__ = [
    "ALL_KINDS",
    "MULTI_KINDS",
    "NON",
    "SINGLE_KINDS",
    "TEMPLATES",
    "Sample",
    "View",
    "build_mosaic",
    "check_kind",
    "mosaic_image",
    "mosaic_sample",
    "single_samples",
]
