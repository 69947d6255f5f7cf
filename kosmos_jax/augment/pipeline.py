"""The augmentation of DESIGN.md section 1, jit-compiled over batches and driven by PRNG keys.

crop 351 (centre policy) -> rotate [0, 360) -> translate +-40 px -> crop 224, composed into one
affine per sample (`affine.recipe_matrix`) and applied once (`warp.warp_images`); the grasps
move by the same matrix (`geometry.transform_grasps`). A grasp whose centre leaves the output
([0, 224) in x and y) is dropped: its mask turns False and it is counted.

Because the chain is one warp of the PHOTO, output corners that the sequential recipe would fill
with padding of the 351 crop (a rotated crop's corners, a translation's edge) show the photo's
real pixels where the photo has them; outside the photo the border rule applies.

Samples per photo: `rotations_per_photo` angles, each with `translations_per_rotation` shifts,
so `augmentations_per_photo = rotations * translations` outputs per photo (the data-size knob of
the scaling study). KOSMOS-E's own script (TX-Leo/KOSMOS-E, data/utils/data/cornell_data.py,
`dataset_augment`) draws, per photo, 4 angles as `np.random.randint(0, 360)` whole degrees and,
for each angle, 4 shifts as `np.random.randint(-40, 41)` whole pixels, unseeded; `PAPER_RECIPE`
does the same draws from a key. (Its grasp corners are also rounded to integers on loading and
after the rotation, and its rotation centre for grasps is 175, half a pixel from the image's;
we keep exact float geometry instead.)

Randomness: one key per photo, so a photo's augmentations do not depend on its batch-mates.
Output rows are photo-major: row b * K + k is augmentation k of photo b.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.augment import affine
from kosmos_jax.augment.warp import BORDERS, warp_images


@dataclasses.dataclass(frozen=True)
class AugmentConfig:
    """Static settings of the augmentation (hashable, so it can be a jit static argument)."""

    crop_size: int = 351
    output_size: int = 224
    centre_policy: str = "gt_centroid"
    max_translation: float = 40.0
    rotations_per_photo: int = 1
    translations_per_rotation: int = 1
    integer_steps: bool = False  # whole degrees and whole-pixel shifts, as KOSMOS-E's script
    border: str = "reflect"

    def __post_init__(self):
        if self.centre_policy not in affine.CENTRE_POLICIES:
            raise ValueError(
                f"centre_policy must be one of {affine.CENTRE_POLICIES}, got {self.centre_policy!r}")
        if self.border not in BORDERS:
            raise ValueError(f"border must be one of {BORDERS}, got {self.border!r}")
        for name in ("crop_size", "output_size", "rotations_per_photo", "translations_per_rotation"):
            value = getattr(self, name)
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        if self.output_size > self.crop_size:
            raise ValueError(
                f"output_size ({self.output_size}) must not exceed crop_size ({self.crop_size})")
        if not self.max_translation >= 0:
            raise ValueError(f"max_translation must be >= 0, got {self.max_translation!r}")

    @property
    def augmentations_per_photo(self) -> int:
        return self.rotations_per_photo * self.translations_per_rotation


PAPER_RECIPE = AugmentConfig(rotations_per_photo=4, translations_per_rotation=4, integer_steps=True)


class AugmentedBatch(NamedTuple):
    """The output of `augment`, B photos x K augmentations flattened photo-major to B * K rows.

    images [B*K, S, S, C] (uint8 in -> uint8 out, float in -> same float out);
    grasps [B*K, N, 5] in output pixels, zero where mask is False;
    mask [B*K, N] bool: the grasp was valid and its centre is inside the output;
    dropped [B*K] int32: valid grasps whose centre left the output;
    matrices [B*K, 2, 3]: the forward affine photo -> output (grasp coordinates);
    photo_index [B*K] int32: the row of the input batch each sample came from.
    """

    images: jax.Array
    grasps: jax.Array
    mask: jax.Array
    dropped: jax.Array
    matrices: jax.Array
    photo_index: jax.Array


def _as_keys(keys, batch):
    """One key per photo: a [B] key array, [B, 2] raw uint32 keys, or a single key to split."""
    keys = jnp.asarray(keys) if not isinstance(keys, jax.Array) else keys
    typed = jnp.issubdtype(keys.dtype, jax.dtypes.prng_key)
    if typed and keys.ndim == 0 or not typed and keys.shape == (2,):
        return jax.random.split(keys, batch)
    if typed and keys.shape == (batch,) or not typed and keys.shape == (batch, 2):
        return keys
    raise ValueError(
        f"keys must be one PRNG key or one per photo ({batch}), got shape {keys.shape} "
        f"dtype {keys.dtype}")


def _photo_draws(key, grasps, mask, image_hw, config):
    """One photo's random draws: crop corner [2], angles [K], shifts [K, 2]."""
    crop_key, angle_key, shift_key = jax.random.split(key, 3)
    corner = affine.crop_corner(crop_key, grasps, mask, image_hw, config.crop_size,
                                config.centre_policy, config.integer_steps)
    rotations, translations = config.rotations_per_photo, config.translations_per_rotation
    angles = affine.sample_rotations(angle_key, rotations, config.integer_steps)
    shifts = affine.sample_translations(
        shift_key, (rotations, translations), config.max_translation, config.integer_steps)
    angles = jnp.repeat(angles, translations)  # each angle shared by its translations
    return corner, angles, shifts.reshape(rotations * translations, 2)


def recipe_matrices(keys, grasps, mask, image_hw, config):
    """[B, K, 2, 3] recipe matrices, one key per photo.

    Only the random draws are vmapped (one key per photo); the matrices are built on the batch.
    """
    corners, angles, shifts = jax.vmap(lambda k, g, m: _photo_draws(k, g, m, image_hw, config))(
        keys, grasps, mask)
    return affine.recipe_matrix(corners[:, None], angles, shifts, config.crop_size, config.output_size)


def move_grasps(grasps, mask, matrices, output_size):
    """Move grasps [B, K, N, 5] (or any leading dims) by matrices [..., 2, 3]; drop and count.

    Returns (grasps zeroed where dropped, mask, dropped count per matrix).
    """
    moved = geometry.transform_grasps(grasps, matrices)
    centre = moved[..., :2]
    inside = jnp.all((centre >= 0) & (centre < output_size), axis=-1)
    kept = mask & inside
    dropped = jnp.sum(mask & ~inside, axis=-1).astype(jnp.int32)
    return jnp.where(kept[..., None], moved, 0.0), kept, dropped


@functools.partial(jax.jit, static_argnames=("config",))
def augment(images, grasps, mask, keys, config: AugmentConfig = AugmentConfig()) -> AugmentedBatch:
    """Augment a batch of photos with their grasps. Pure; all randomness comes from `keys`.

    images [B, H, W, C] uint8 or float; grasps [B, N, 5] (x, y, w, h, theta) in photo pixels,
    padded; mask [B, N] bool marks the real grasps; keys: one key per photo ([B] typed keys or
    [B, 2] uint32) or a single key that is split. Returns an AugmentedBatch of B * K rows,
    K = config.augmentations_per_photo.
    """
    if images.ndim != 4:
        raise ValueError(f"images must be [B, H, W, C], got shape {images.shape}")
    batch, height, width, _ = images.shape
    if grasps.ndim != 3 or grasps.shape[0] != batch or grasps.shape[2] != 5:
        raise ValueError(f"grasps must be [B={batch}, N, 5], got shape {grasps.shape}")
    if mask.shape != grasps.shape[:2]:
        raise ValueError(f"mask must be [B, N] = {grasps.shape[:2]}, got shape {mask.shape}")
    if mask.dtype != jnp.bool_:
        raise ValueError(f"mask must be bool, got dtype {mask.dtype}")
    keys = _as_keys(keys, batch)
    per_photo = config.augmentations_per_photo
    grasps = grasps.astype(jnp.float32)
    matrices = recipe_matrices(keys, grasps, mask, (height, width), config)  # [B, K, 2, 3]
    size = config.output_size
    warped = warp_images(images, matrices, (size, size), config.border)
    repeated = jnp.broadcast_to(grasps[:, None], (batch, per_photo) + grasps.shape[1:])
    repeated_mask = jnp.broadcast_to(mask[:, None], (batch, per_photo) + mask.shape[1:])
    moved, kept, dropped = move_grasps(repeated, repeated_mask, matrices, size)
    rows = batch * per_photo
    return AugmentedBatch(
        images=warped.reshape((rows,) + warped.shape[2:]),
        grasps=moved.reshape(rows, -1, 5),
        mask=kept.reshape(rows, -1),
        dropped=dropped.reshape(rows),
        matrices=matrices.reshape(rows, 2, 3),
        photo_index=jnp.repeat(jnp.arange(batch, dtype=jnp.int32), per_photo),
    )


def pad_grasps(grasp_lists, max_grasps=None):
    """Pad a list of [N_i, 5] grasp arrays to ([B, N, 5] float32, [B, N] bool mask) in numpy.

    N = max_grasps, or the longest list. A list longer than max_grasps is an error naming it.
    """
    lengths = [int(np.shape(g)[0]) for g in grasp_lists]
    width = max(lengths, default=0) if max_grasps is None else int(max_grasps)
    grasps = np.zeros((len(grasp_lists), width, 5), np.float32)
    mask = np.zeros((len(grasp_lists), width), bool)
    for row, (g, n) in enumerate(zip(grasp_lists, lengths)):
        g = np.asarray(g, np.float32)
        if g.ndim != 2 or g.shape[1] != 5:
            raise ValueError(f"grasp list {row} must be [N, 5], got shape {g.shape}")
        if n > width:
            raise ValueError(f"grasp list {row} has {n} grasps, more than max_grasps={width}")
        grasps[row, :n] = g
        mask[row, :n] = True
    return grasps, mask


def kept_grasps(batch: AugmentedBatch, row: int):
    """(grasps [M, 5], grasp_ids [M]) of one output row, numpy: the surviving grasps and their
    indices in the photo's own grasp list (for instruct.sample.View.grasp_ids)."""
    mask = np.asarray(batch.mask[row])
    ids = np.flatnonzero(mask)
    return np.asarray(batch.grasps[row])[ids].astype(np.float64), ids
