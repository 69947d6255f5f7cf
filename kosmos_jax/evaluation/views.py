"""The 224 x 224 test views of photos under each protocol, with their ground truths moved along.

honest: one view per photo, a 351 crop at the photo's centre (never at the labels), no rotation,
  no shift, then the central 224.
paper: KOSMOS-E's public code evaluates on augmented copies: 351 crops centred on the mean of the
  ground-truth corners, whole-degree rotations and whole-pixel shifts of up to 40 px, `copies` per
  photo (3 rotations x 3 shifts = 9, the 885 x 9 set its fold code is written for).
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.augment import AugmentConfig, augment, move_grasps, pad_grasps, warp_images
from kosmos_jax.augment.affine import crop_corner, recipe_matrix
from kosmos_jax.data.photo import Photo

PROTOCOLS = ("honest", "paper")
PAPER_VIEWS = AugmentConfig(centre_policy="gt_centroid", rotations_per_photo=3, translations_per_rotation=3, integer_steps=True)
HONEST_CROP = AugmentConfig(centre_policy="image_centre", max_translation=0.0)


@dataclasses.dataclass
class Views:
    """Test views: row i is copy `copy[i]` of photo `photo_id[i]`."""

    images: np.ndarray  # [V, 224, 224, 3] uint8
    grasps: np.ndarray  # [V, N, 5] in view pixels
    mask: np.ndarray  # [V, N] bool
    photo_id: list[str]
    copy: np.ndarray  # [V] int
    dropped: int  # ground truths whose centre left the view


@jax.jit
def _centre_views(images, grasps, mask):
    corners = jax.vmap(lambda g, m: crop_corner(None, g, m, images.shape[1:3], HONEST_CROP.crop_size, "image_centre", False))(grasps, mask)
    zeros = jnp.zeros(images.shape[:1], jnp.float32)
    matrices = recipe_matrix(corners, zeros, jnp.zeros_like(corners), HONEST_CROP.crop_size, HONEST_CROP.output_size)
    size = HONEST_CROP.output_size
    warped = warp_images(images, matrices[:, None], (size, size), HONEST_CROP.border)[:, 0]
    moved, kept, dropped = move_grasps(grasps, mask, matrices, size)
    return warped, moved, kept, dropped


def _chunks(photos: Sequence[Photo], size: int):
    """Consecutive runs of photos with the same image shape, at most `size` long."""
    start = 0
    while start < len(photos):
        stop = start + 1
        while stop < len(photos) and stop - start < size and photos[stop].rgb.shape == photos[start].rgb.shape:
            stop += 1
        yield photos[start:stop]
        start = stop


def make_views(photos: Sequence[Photo], protocol: str = "honest", seed: int = 0, chunk: int = 32, progress: bool = False) -> Views:
    """Test views of `photos` (with images) under `protocol`; deterministic for a seed."""
    if protocol not in PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; expected one of {PROTOCOLS}")
    for photo in photos:
        if photo.rgb is None:
            raise ValueError(f"photo {photo.id} has no image: read it with load_images=True")
    width = max((len(p.grasps) for p in photos), default=0)
    key = jax.random.key(seed)
    parts, done = [], 0
    for group in _chunks(list(photos), chunk):
        images = jnp.asarray(np.stack([p.rgb for p in group]))
        grasps, mask = pad_grasps([p.grasps for p in group], width)
        if protocol == "honest":
            out = _centre_views(images, jnp.asarray(grasps), jnp.asarray(mask))
            copies = 1
        else:
            keys = jax.random.split(jax.random.fold_in(key, done), len(group))
            batch = augment(images, jnp.asarray(grasps), jnp.asarray(mask), keys, PAPER_VIEWS)
            out = (batch.images, batch.grasps, batch.mask, batch.dropped)
            copies = PAPER_VIEWS.augmentations_per_photo
        parts.append(([p.id for p in group for _ in range(copies)], np.tile(np.arange(copies), len(group)), *map(np.asarray, out)))
        done += len(group)
        if progress:
            print(f"views ({protocol}): {done}/{len(photos)} photos", file=sys.stderr, flush=True)
    if not parts:
        raise ValueError("no photos to make views of")
    return Views(
        images=np.concatenate([p[2] for p in parts]),
        grasps=np.concatenate([p[3] for p in parts]),
        mask=np.concatenate([p[4] for p in parts]),
        photo_id=[i for p in parts for i in p[0]],
        copy=np.concatenate([p[1] for p in parts]),
        dropped=int(sum(p[5].sum() for p in parts)),
    )
