"""The baselines' inputs: photos and a fold -> normalised RGB, depth or RGB-D 224 views with their grasps.

    views = fold_views(photos, "rgbd", fold=0, scheme="object")          # honest protocol
    for batch in batches(views.train, batch_size=8, seed=0): ...           # {"image", "grasps", "mask"}

The views are KOSMOS-E's (kosmos_jax.dataset.build): the same folds (kosmos_jax.sources.splits, decided
over photos or object ids before any augmentation), the same augmentation settings
(`dataset.views.augment_config`: crop 351 -> rotate -> translate -> crop 224, `copies` per training
photo) and the same keys (photo i of the list gets fold_in(PRNGKey(seed), i); the honest test views
use seed + 1 and are the un-rotated image-centre crop). So with one seed the RGB channels here are
the images KOSMOS-E trains and is scored on, up to uint8 rounding. The `public` protocol (the
baselines' own, package docstring) trains on the same augmented views of its split's training
photos and tests on PUBLIC_TEST_CROP: the 224 window centred on the ground truths' mean, clamped to
the photo, copied as it is (no rotation, zoom 1: their evaluate.py without --augment). The depth map is stacked with the
RGB as a fourth channel BEFORE the warp, so it moves with the pixels (`augment` warps any channel
count and float images).

Normalisation per view, after the warp, as GG-CNN and GR-ConvNet do per crop: RGB / 255 minus the
view's mean (one scalar over its three channels); depth minus the view's mean, clipped to [-1, 1].
Channels: depth [D], rgb [R, G, B], rgbd [R, G, B, D].

Depth: Cornell's pcdXXXXd.tiff where present, the rendered depth of synthetic scenes. A photo without
depth cannot make depth or RGB-D views: `fold_views` splits first (so the folds are KOSMOS-E's) and
then leaves such photos out of both sides, listing them in `missing_depth`. A depth map with a NaN or
infinite value is an error naming the photo (the public code inpaints missing depth when it writes
the tiffs; ours are read as they are).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Iterator, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.augment import affine
from kosmos_jax.augment.pipeline import AugmentConfig, augment, move_grasps, pad_grasps
from kosmos_jax.augment.warp import warp_images
from kosmos_jax.baselines.layers import input_channels
from kosmos_jax.sources import splits
from kosmos_jax.sources.photo import Photo
from kosmos_jax.dataset.views import HONEST_TEST_CROP, augment_config

BATCH_KEYS = ("image", "grasps", "mask")
# GR-ConvNet's and GG-CNN's test crop (_get_crop_attrs): output_size centred on the truncated mean of the
# ground-truth corners, clamped to the photo; crop_size = output_size, so nothing is resampled.
PUBLIC_TEST_CROP = AugmentConfig(crop_size=224, output_size=224, centre_policy="gt_centroid", max_translation=0.0,
                                 integer_steps=True)


def needs_depth(mode: str) -> bool:
    return input_channels(mode) != 3


def photo_channels(photo: Photo, mode: str) -> np.ndarray:
    """[H, W, C] float32 of one photo, not normalised: RGB in 0..255, depth as read."""
    input_channels(mode)
    if photo.rgb is None:
        raise ValueError(f"photo {photo.id} was read without its image (load_images=False)")
    layers = [] if mode == "depth" else [photo.rgb.astype(np.float32)]
    if needs_depth(mode):
        if photo.depth is None:
            raise ValueError(f"photo {photo.id} has no depth map; mode {mode!r} needs one")
        if not np.all(np.isfinite(photo.depth)):
            raise ValueError(f"photo {photo.id}: its depth map has NaN or infinite values")
        layers.append(photo.depth.astype(np.float32)[..., None])
    return np.concatenate(layers, axis=-1)


@functools.partial(jax.jit, static_argnames=("mode",))
def normalise(images: jax.Array, mode: str) -> jax.Array:
    """Per-view normalisation of [V, H, W, C] views from `photo_channels` (see the module docstring)."""
    images = images.astype(jnp.float32)
    parts = []
    if mode != "depth":
        rgb = images[..., :3] / 255.0
        parts.append(rgb - jnp.mean(rgb, axis=(1, 2, 3), keepdims=True))
    if needs_depth(mode):
        depth = images[..., -1:]
        parts.append(jnp.clip(depth - jnp.mean(depth, axis=(1, 2, 3), keepdims=True), -1.0, 1.0))
    return jnp.concatenate(parts, axis=-1)


@dataclasses.dataclass
class ViewArrays:
    """Views in (photo id, copy) order: row i is copy `copy[i]` of photo `photo_id[i]`."""

    images: np.ndarray  # [V, S, S, C] float32 (normalised unless asked otherwise)
    grasps: np.ndarray  # [V, N, 5] float32 in view pixels, zero where mask is False
    mask: np.ndarray  # [V, N] bool
    photo_id: list[str]
    copy: np.ndarray  # [V] int
    dropped: int = 0  # ground truths whose centre left their view
    without_grasps: int = 0  # views left with no grasp, not kept

    def __len__(self) -> int:
        return len(self.photo_id)

    def select(self, keys: Sequence[tuple[str, int]]) -> "ViewArrays":
        """The views named by (photo id, copy) pairs, in that order; pairs with no view are skipped."""
        row = {(p, int(c)): i for i, (p, c) in enumerate(zip(self.photo_id, self.copy))}
        rows = np.asarray([row[tuple(k)] for k in keys if tuple(k) in row], np.int64)
        return ViewArrays(self.images[rows], self.grasps[rows], self.mask[rows], [self.photo_id[i] for i in rows],
                          self.copy[rows], self.dropped, self.without_grasps)


@functools.partial(jax.jit, static_argnames=("config",))
def _crop(images, grasps, mask, keys, config: AugmentConfig):
    """One view a photo: the recipe's crop with no rotation or shift, then its central window."""
    height, width = images.shape[1:3]
    def corner(key, g, m):
        return affine.crop_corner(key, g, m, (height, width), config.crop_size, config.centre_policy,
                                  config.integer_steps)

    corners = jax.vmap(corner)(keys, grasps, mask)
    zeros = jnp.zeros(corners.shape[:1], jnp.float32)
    matrices = affine.recipe_matrix(corners, zeros, jnp.zeros_like(corners), config.crop_size, config.output_size)
    size = config.output_size
    moved, kept, dropped = move_grasps(grasps, mask, matrices, size)
    return warp_images(images, matrices, (size, size), config.border), moved, kept, dropped


def make_views(photos: Sequence[Photo], mode: str, config: AugmentConfig, seed: int, photo_index: dict[str, int],
               crop_only: bool = False, batch_size: int = 8, normalised: bool = True) -> ViewArrays:
    """Views of `photos`: `config.augmentations_per_photo` augmented copies each, or with crop_only one
    un-rotated crop; photo p's key is fold_in(PRNGKey(seed), photo_index[p.id])."""
    if not photos:
        raise ValueError("no photos to make views of")
    base = jax.random.PRNGKey(seed)
    width = max(8, -(-max(len(p.grasps) for p in photos) // 8) * 8)
    by_shape: dict[tuple, list[Photo]] = {}
    for photo in photos:
        if photo.rgb is None:
            raise ValueError(f"photo {photo.id} was read without its image (load_images=False)")
        by_shape.setdefault(photo.rgb.shape[:2], []).append(photo)
    rows, dropped, without = {}, 0, 0
    for group in by_shape.values():
        for start in range(0, len(group), batch_size):
            chosen = group[start:start + batch_size]
            padded = chosen + [chosen[-1]] * (batch_size - len(chosen))  # one compile per shape
            images = jnp.asarray(np.stack([photo_channels(p, mode) for p in padded]))
            grasps, mask = (jnp.asarray(a) for a in pad_grasps([p.grasps for p in padded], width))
            keys = jnp.stack([jax.random.fold_in(base, photo_index[p.id]) for p in padded])
            if crop_only:
                out = _crop(images, grasps, mask, keys, config)
                copies = 1
            else:
                batch = augment(images, grasps, mask, keys, config)
                out = (batch.images, batch.grasps, batch.mask, batch.dropped)
                copies = config.augmentations_per_photo
            views = normalise(out[0], mode) if normalised else out[0]
            views, moved, kept, lost = (np.asarray(a) for a in (views, *out[1:]))
            for slot, photo in enumerate(chosen):
                for copy in range(copies):
                    row = slot * copies + copy
                    dropped += int(lost[row])
                    if not kept[row].any():
                        without += 1
                        continue
                    rows[(photo.id, copy)] = (views[row], moved[row], kept[row])
    order = sorted(rows)
    if not order:
        raise ValueError("every view lost all its grasps")
    return ViewArrays(np.stack([rows[k][0] for k in order]), np.stack([rows[k][1] for k in order]).astype(np.float32),
                      np.stack([rows[k][2] for k in order]), [k[0] for k in order], np.asarray([k[1] for k in order]),
                      dropped, without)


@dataclasses.dataclass
class FoldViews:
    train: ViewArrays
    test: ViewArrays
    missing_depth: list[str]  # photos of the fold left out for want of a depth map
    protocol: str
    scheme: str
    validation: ViewArrays | None = None  # training photos held out (validation_fraction > 0), made as test's


def fold_views(photos: Sequence[Photo], mode: str, fold: int, scheme: str = "image", protocol: str = "honest",
               k: int = 5, fold_seed: int | None = None, copies: int = 16, recipe: str = "random", seed: int = 0,
               train_crop: str = "gt_centroid", test_crop: str = "image_centre", batch_size: int = 8,
               validation_fraction: float = 0.0) -> FoldViews:
    """Train and test views of fold `fold`, as KOSMOS-E's build makes them for the same settings.

    honest: `copies` augmented views of each training photo (key seed) and one un-rotated `test_crop`
      crop of each test photo (seed + 1). paper: `copies` augmented copies of every photo, all with
      `train_crop`, and the public code's folds over those copies. public: the GR-ConvNet / GG-CNN
      split (fold 0 only, splits.public_split), training views as honest's, PUBLIC_TEST_CROP test views.
    validation_fraction > 0 (honest and public): that share of the training photos (object-wise: whole
      objects) held out as the build holds them out (`splits.validation_split`, the fold seed), their
      views made as the test views are; schedules are chosen on them, never on test.
    """
    if protocol not in splits.PROTOCOLS:
        raise ValueError(f"protocol {protocol!r} must be one of {', '.join(splits.PROTOCOLS)}")
    if splits.check_validation_fraction(validation_fraction) and protocol == "paper":
        raise ValueError(f"validation_fraction={validation_fraction}: the paper protocol folds augmented copies of "
                         "every photo, so no photo is left to hold out; use the honest or public protocol")
    photos = list(photos)
    index = {p.id: i for i, p in enumerate(photos)}
    ids = [p.id for p in photos]
    object_ids = [p.object_id for p in photos] if scheme == "object" else None
    # fold_seed None: each protocol's own default (honest 0, paper and public the public code's 123)
    chosen = splits.split(ids, fold, scheme, protocol, object_ids=object_ids, k=k, seed=fold_seed,
                          copies_per_photo=copies)
    missing = sorted(p.id for p in photos if needs_depth(mode) and p.depth is None)
    usable = {p.id: p for p in photos if p.id not in missing}
    if protocol in ("honest", splits.PUBLIC):
        object_of = dict(zip(ids, object_ids)) if object_ids else None
        train_ids, validation_ids = splits.validation_split(
            chosen.train, validation_fraction, scheme, seed=splits.fold_seed(protocol, fold_seed),
            object_ids=[object_of[i] for i in chosen.train] if object_of else None)
        train_photos = [usable[i] for i in train_ids if i in usable]
        test_photos = [usable[i] for i in chosen.test if i in usable]
        train = make_views(train_photos, mode, augment_config(copies, recipe, train_crop), seed, index,
                           batch_size=batch_size)
        if protocol == splits.PUBLIC:
            test_config = PUBLIC_TEST_CROP
        elif test_crop == HONEST_TEST_CROP.centre_policy:
            test_config = HONEST_TEST_CROP
        else:
            test_config = dataclasses.replace(HONEST_TEST_CROP, centre_policy=test_crop)
        test = make_views(test_photos, mode, test_config, seed + 1, index, crop_only=True, batch_size=batch_size)
        validation = None
        if validation_ids:  # the test crop and seed, as the build makes validation views
            validation = make_views([usable[i] for i in validation_ids if i in usable], mode, test_config, seed + 1,
                                    index, crop_only=True, batch_size=batch_size)
        return FoldViews(train, test, missing, protocol, scheme, validation)
    every = make_views(list(usable.values()), mode, augment_config(copies, recipe, train_crop), seed, index,
                       batch_size=batch_size)
    return FoldViews(every.select(chosen.train), every.select(chosen.test), missing, protocol, scheme)


def batch_rows(count: int, batch_size: int, seed: int, step: int) -> np.ndarray:
    """The view rows of training step `step`: epochs of a seeded permutation, the remainder dropped."""
    per_epoch = count // batch_size
    if per_epoch == 0:
        raise ValueError(f"{count} views make no batch of {batch_size}")
    epoch, position = divmod(step, per_epoch)
    order = np.random.default_rng([seed, epoch]).permutation(count)
    return order[position * batch_size:(position + 1) * batch_size]


def batches(views: ViewArrays, batch_size: int, seed: int, start_step: int = 0) -> Iterator[dict[str, np.ndarray]]:
    """Endless training batches {"image", "grasps", "mask", "rows"}; batch s depends on (seed, s) only,
    so a run resumed at step s sees the batches of the run it resumes."""
    step = start_step
    while True:
        rows = batch_rows(len(views), batch_size, seed, step)
        yield {"image": views.images[rows], "grasps": views.grasps[rows], "mask": views.mask[rows], "rows": rows}
        step += 1


def eval_batches(views: ViewArrays, batch_size: int) -> Iterator[dict[str, np.ndarray]]:
    """Every view once, in order, the last batch padded by repeating its last row (rows -1 mark padding)."""
    for start in range(0, len(views), batch_size):
        rows = np.arange(start, min(start + batch_size, len(views)))
        padded = np.concatenate([rows, np.full(batch_size - len(rows), rows[-1])])
        marks = np.concatenate([rows, np.full(batch_size - len(rows), -1)])
        yield {"image": views.images[padded], "grasps": views.grasps[padded], "mask": views.mask[padded],
               "rows": marks}


__all__ = ["BATCH_KEYS", "PUBLIC_TEST_CROP", "FoldViews", "ViewArrays", "batch_rows", "batches", "eval_batches",
           "fold_views", "make_views", "needs_depth", "normalise", "photo_channels"]
