"""Photos -> 224 x 224 views with their grasps, through the jit augmentation (kosmos_jax.augment).

Two kinds of view:
- `augmented_views`: `copies` augmentations per photo (crop 351 -> rotate -> translate -> crop
  224), the training views of either protocol and the test views of the paper protocol.
  recipe "random": `copies` rotations with one translation each; "paper": KOSMOS-E's script,
  copies / 4 whole-degree rotations with 4 whole-pixel translations each (16 copies = 4 x 4).
- `cropped_views`: one view per photo, the 351 crop's central 224 window with no rotation or
  translation: the honest protocol's test views (with a crop policy that does not look at the
  ground truth, "image_centre" by default).

Each photo gets its own PRNG key, `fold_in(PRNGKey(seed), index in the sorted photo list)`, so a
photo's views do not depend on its batch-mates or on the batch size. Grasps whose centre leaves the
view are dropped and counted; a view left with no grasp is skipped and counted.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.augment import affine
from kosmos_jax.augment.pipeline import AugmentConfig, augment, kept_grasps, move_grasps, pad_grasps
from kosmos_jax.augment.warp import warp_images
from kosmos_jax.instruct.sample import View

RECIPES = ("random", "paper")


@dataclasses.dataclass
class ViewCounts:
    views: int = 0
    grasps_dropped_by_crop: int = 0
    views_without_grasps: int = 0



def augment_config(copies: int, recipe: str, crop_policy: str, output_size: int = 224) -> AugmentConfig:
    if recipe not in RECIPES:
        raise ValueError(f"unknown augmentation recipe {recipe!r}; expected one of {RECIPES}")
    if copies < 1:
        raise ValueError(f"augmentations per photo must be at least 1, got {copies}")
    if recipe == "paper":
        if copies % 4:
            raise ValueError(f"the paper recipe makes 4 translations per rotation; {copies} augmentations is not a multiple of 4")
        return AugmentConfig(centre_policy=crop_policy, rotations_per_photo=copies // 4, translations_per_rotation=4,
                             integer_steps=True, output_size=output_size)
    return AugmentConfig(centre_policy=crop_policy, rotations_per_photo=copies, translations_per_rotation=1,
                         output_size=output_size)


@functools.partial(jax.jit, static_argnames=("config",))
def _crop(images, grasps, mask, keys, config: AugmentConfig):
    """The crop of the recipe without rotation or translation: [B] views."""
    height, width = images.shape[1:3]
    corners = jax.vmap(lambda k, g, m: affine.crop_corner(
        k, g, m, (height, width), config.crop_size, config.centre_policy, config.integer_steps))(keys, grasps, mask)
    zeros = jnp.zeros(corners.shape[:1], jnp.float32)
    matrices = affine.recipe_matrix(corners, zeros, jnp.zeros_like(corners), config.crop_size, config.output_size)
    size = config.output_size
    warped = warp_images(images, matrices, (size, size), config.border)
    moved, kept, dropped = move_grasps(grasps.astype(jnp.float32), mask, matrices, size)
    return warped, moved, kept, dropped


def _batches(photos: Sequence, batch_size: int):
    """Photos grouped by image shape, in batches of at most `batch_size`, with their list index."""
    by_shape: dict[tuple, list[int]] = {}
    for index, photo in enumerate(photos):
        by_shape.setdefault(photo.rgb.shape, []).append(index)
    for indices in by_shape.values():
        for start in range(0, len(indices), batch_size):
            yield indices[start : start + batch_size]


def _run(photos, indices, keys_of, config, batch_size, width, crop_only):
    """One padded batch through the jit function (fixed batch and grasp width: one compile)."""
    chosen = [photos[i] for i in indices]
    padded = chosen + [chosen[-1]] * (batch_size - len(chosen))
    images = np.stack([p.rgb for p in padded])
    grasps, mask = pad_grasps([p.grasps for p in padded], width)
    keys = jnp.stack([keys_of(i) for i in indices + [indices[-1]] * (batch_size - len(indices))])
    if crop_only:
        warped, moved, kept, dropped = _crop(images, grasps, mask, keys, config)
        return warped, moved, kept, dropped, 1
    out = augment(images, grasps, mask, keys, config)
    return out.images, out.grasps, out.mask, out.dropped, config.augmentations_per_photo


def make_views(
    photos: Sequence,
    words: Mapping[str, object],
    config: AugmentConfig,
    seed: int,
    photo_index: Mapping[str, int],
    crop_only: bool = False,
    batch_size: int = 8,
) -> tuple[dict[tuple[str, int], View], dict[tuple[str, int], int]]:
    """({(photo id, copy): View}, {(photo id, copy): grasps dropped}) of every view made.

    `photo_index` numbers photos for their keys. A (photo, copy) missing from the views but present
    in the dropped counts had no grasp left.
    """
    base = jax.random.PRNGKey(seed)
    keys_of = lambda i: jax.random.fold_in(base, photo_index[photos[i].id])
    views: dict[tuple[str, int], View] = {}
    dropped_by_view: dict[tuple[str, int], int] = {}
    if not photos:
        return views, dropped_by_view
    width = max(8, -(-max(len(p.grasps) for p in photos) // 8) * 8)
    for indices in _batches(photos, batch_size):
        images, grasps, kept, dropped, per_photo = _run(photos, indices, keys_of, config, batch_size, width, crop_only)
        images, dropped = np.asarray(images), np.asarray(dropped)
        batch = _Rows(grasps, kept)
        for slot, index in enumerate(indices):
            photo = photos[index]
            for copy in range(per_photo):
                row = slot * per_photo + copy
                dropped_by_view[(photo.id, copy)] = int(dropped[row])
                view_grasps, ids = kept_grasps(batch, row)
                if len(ids) == 0:
                    continue
                views[(photo.id, copy)] = View(
                    photo_id=photo.id,
                    image=images[row],
                    grasps=view_grasps,
                    words=words.get(photo.id),
                    object_id=photo.object_id,
                    grasp_ids=ids,
                )
    return views, dropped_by_view


def count_views(keys, views: Mapping, dropped_by_view: Mapping) -> ViewCounts:
    """The counts of the views named by `keys` ((photo id, copy) pairs)."""
    keys = list(keys)
    return ViewCounts(
        views=len(keys),
        grasps_dropped_by_crop=sum(dropped_by_view[k] for k in keys),
        views_without_grasps=sum(k not in views for k in keys),
    )


class _Rows:
    """The two fields of an AugmentedBatch that `kept_grasps` reads."""

    def __init__(self, grasps, mask):
        self.grasps, self.mask = np.asarray(grasps), np.asarray(mask)
