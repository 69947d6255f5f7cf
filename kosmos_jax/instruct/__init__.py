"""Stage 4, INSTRUCT-GRASP instructions: views and words in, `Sample`s out.

NON, SINGLE (8 kinds) and MULTI (2 x 2 mosaics, 6 kinds): each sample is an instruction sentence,
an image and every grasp that answers it, with the photo and object ids inside the image.
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
