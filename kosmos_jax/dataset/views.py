"""Photos -> 224 x 224 views with their grasps, through the jit augmentation (kosmos_jax.augment).

Two kinds of view:
- `augmented_views`: `copies` augmentations per photo (crop 351 -> rotate -> translate -> crop
  224), the training views of either protocol and the test views of the paper protocol.
  recipe "random": `copies` rotations with one translation each; "paper": KOSMOS-E's script,
  copies / 4 whole-degree rotations with 4 whole-pixel translations each (16 copies = 4 x 4).
- `cropped_views`: one view per photo, the 351 crop's central 224 window with no rotation or
  translation: the honest protocol's test views, and its validation views, made the same way
  (with a crop policy that does not look at the ground truth, "image_centre" by default).

Each photo gets its own PRNG key, `fold_in(PRNGKey(seed), index in the sorted photo list)`, so a
photo's views do not depend on its batch-mates or on the batch size. Grasps whose centre leaves the
view are dropped and counted; a view left with no grasp is skipped and counted.

The no-learning evaluation (`evaluation_views`) takes its test views from here too, as arrays:
honest: one view per photo, the 351 crop at the photo's centre (never at the labels), no rotation,
  no shift, then the central 224 (`cropped_views`' crop with HONEST_TEST_CROP).
paper: KOSMOS-E's public code evaluates on augmented copies: 351 crops centred on the mean of the
  ground-truth corners, whole-degree rotations and whole-pixel shifts of up to 40 px, `copies` per
  photo (3 rotations x 3 shifts = 9, the 885 x 9 set its fold code is written for: PAPER_TEST_VIEWS).
"""

from __future__ import annotations

import dataclasses
import functools
import sys
from typing import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.augment import affine
from kosmos_jax.augment.pipeline import AugmentConfig, augment, kept_grasps, move_grasps, pad_grasps
from kosmos_jax.augment.warp import warp_images
from kosmos_jax.sources import splits
from kosmos_jax.sources.photo import Photo
from kosmos_jax.instruct.sample import View

RECIPES = ("random", "paper")
PROTOCOLS = splits.KOSMOS_E_PROTOCOLS
PAPER_TEST_VIEWS = AugmentConfig(centre_policy="gt_centroid", rotations_per_photo=3, translations_per_rotation=3,
                                 integer_steps=True)
HONEST_TEST_CROP = AugmentConfig(centre_policy="image_centre", max_translation=0.0)


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


def crop_matrices(keys, grasps, mask, image_shape: tuple[int, int], config: AugmentConfig):
    """[B, 2, 3] the affines of the recipe's crop without rotation or translation, photo pixels -> view pixels."""
    corners = jax.vmap(lambda k, g, m: affine.crop_corner(
        k, g, m, image_shape, config.crop_size, config.centre_policy, config.integer_steps))(keys, grasps, mask)
    zeros = jnp.zeros(corners.shape[:1], jnp.float32)
    return affine.recipe_matrix(corners, zeros, jnp.zeros_like(corners), config.crop_size, config.output_size)


@functools.partial(jax.jit, static_argnames=("config",))
def _crop(images, grasps, mask, keys, config: AugmentConfig):
    """The crop of the recipe without rotation or translation: [B] views."""
    matrices = crop_matrices(keys, grasps, mask, images.shape[1:3], config)
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


# -- the no-learning evaluation's test views, as arrays -------------------------------------------

@dataclasses.dataclass
class Views:
    """Test views: row i is copy `copy[i]` of photo `photo_id[i]`."""

    images: np.ndarray  # [V, 224, 224, 3] uint8
    grasps: np.ndarray  # [V, N, 5] in view pixels
    mask: np.ndarray  # [V, N] bool
    photo_id: list[str]
    copy: np.ndarray  # [V] int
    dropped: int  # ground truths whose centre left the view


def _runs_of_one_shape(photos: Sequence[Photo], size: int):
    """Consecutive runs of photos with the same image shape, at most `size` long."""
    start = 0
    while start < len(photos):
        stop = start + 1
        while stop < len(photos) and stop - start < size and photos[stop].rgb.shape == photos[start].rgb.shape:
            stop += 1
        yield photos[start:stop]
        start = stop


def evaluation_views(photos: Sequence[Photo], protocol: str = "honest", seed: int = 0, chunk: int = 32,
                     progress: bool = False) -> Views:
    """Test views of `photos` (with images) under `protocol`; deterministic for a seed."""
    splits.check_kosmos_e_protocol(protocol, "KOSMOS-E's evaluation views")
    for photo in photos:
        if photo.rgb is None:
            raise ValueError(f"photo {photo.id} has no image: read it with load_images=True")
    width = max((len(p.grasps) for p in photos), default=0)
    key = jax.random.key(seed)
    parts, done = [], 0
    for group in _runs_of_one_shape(list(photos), chunk):
        images = jnp.asarray(np.stack([p.rgb for p in group]))
        grasps, mask = pad_grasps([p.grasps for p in group], width)
        if protocol == "honest":
            unused_keys = jax.random.split(jax.random.PRNGKey(0), len(group))  # the image-centre crop draws nothing
            out = _crop(images, jnp.asarray(grasps), jnp.asarray(mask), unused_keys, HONEST_TEST_CROP)
            copies = 1
        else:
            keys = jax.random.split(jax.random.fold_in(key, done), len(group))
            batch = augment(images, jnp.asarray(grasps), jnp.asarray(mask), keys, PAPER_TEST_VIEWS)
            out = (batch.images, batch.grasps, batch.mask, batch.dropped)
            copies = PAPER_TEST_VIEWS.augmentations_per_photo
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
