"""INSTRUCT-GRASP-MULTI: four augmented photos in a 2 x 2 mosaic, 448 -> 224.

Quadrants are numbered 0 top left, 1 top right, 2 bottom left, 3 bottom right. The 448 x 448
mosaic is halved by a 2 x 2 average (`downsample_2x`), rounded half up for uint8; that is exactly
cv2.resize(..., interpolation=cv2.INTER_AREA) for a 2x reduction, and it is a jit-able reshape.
(The KOSMOS-E code blended 15 px seams and used cv2's default bilinear resize, and moved grasp
corners by int(x // 2); we keep the tiles intact and move grasps exactly.)

With the pixel-corner origin of DESIGN.md, output pixel (i, j) covers input pixels [2i, 2i + 2) x
[2j, 2j + 2), so a point of tile q at (x, y) lands at ((x + ox) / 2, (y + oy) / 2), (ox, oy) the
tile's corner in the 448 mosaic: the affine [[0.5, 0, ox / 2], [0, 0.5, oy / 2]], exactly.

Position instructions in a mosaic name either the target's quadrant ("top left", the paper's
code; `position_mode="quadrant"`) or the 3 x 3 cell of the target grasps' centroid in the mosaic
(`position_mode="cell"`); in cell mode a distractor whose centroid falls in the same cell is
ambiguous.
"""

from __future__ import annotations

from typing import Sequence

import cv2
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.annotators.base import require
from kosmos_jax.instruct import distractors as distractor_choice
from kosmos_jax.annotators import position as position_words
from kosmos_jax.instruct.kinds import ANSWERS, MULTI_KINDS, check_kind
from kosmos_jax.instruct.sample import Sample, View
from kosmos_jax.instruct.sentences import object_sentence, position_sentence

POSITION_MODES = ("quadrant", "cell")


def downsample_2x(image):
    """[..., 2H, 2W, C] -> [..., H, W, C] by 2 x 2 averages; numpy or jax (jit-able)."""
    xp = geometry.array_module(image)
    height, width = image.shape[-3], image.shape[-2]
    if height % 2 or width % 2:
        raise ValueError(f"downsample_2x needs even height and width, got {height} x {width}")
    if xp is np and image.dtype == np.uint8 and image.ndim == 3 and image.shape[-1] in (1, 3, 4):
        # the same 2 x 2 means, rounded alike, about ten times faster than the array arithmetic below
        halved = cv2.resize(image, (width // 2, height // 2), interpolation=cv2.INTER_AREA)
        return halved.reshape(height // 2, width // 2, image.shape[-1])
    wide = xp.uint16 if image.dtype == xp.uint8 else image.dtype
    corners = [image[..., i::2, j::2, :].astype(wide) for i in (0, 1) for j in (0, 1)]
    total = (corners[0] + corners[1]) + (corners[2] + corners[3])
    if image.dtype == xp.uint8:
        return ((total + 2) // 4).astype(xp.uint8)  # round half up, as cv2.INTER_AREA does
    return total / 4


def tile_images(images: Sequence):
    """Four [S, S, C] tiles -> one [2S, 2S, C] mosaic in quadrant order; numpy or jax."""
    if len(images) != 4:
        raise ValueError(f"a mosaic needs 4 images, got {len(images)}")
    shapes = {tuple(np.shape(i)) for i in images}
    if len(shapes) != 1:
        raise ValueError(f"mosaic tiles must share one shape, got {sorted(shapes)}")
    (shape,) = shapes
    if len(shape) != 3 or shape[0] != shape[1]:
        raise ValueError(f"mosaic tiles must be square [S, S, C], got {shape}")
    xp = geometry.array_module(*images)
    top = xp.concatenate([images[0], images[1]], axis=1)
    bottom = xp.concatenate([images[2], images[3]], axis=1)
    return xp.concatenate([top, bottom], axis=0)


def mosaic_image(images: Sequence):
    """Four [S, S, C] tiles -> the [S, S, C] mosaic (tiled to 2S, halved); jit-able."""
    return downsample_2x(tile_images(images))


def quadrant_matrix(quadrant: int, tile_size: int) -> np.ndarray:
    """The 2 x 3 affine from a tile's pixels to the halved mosaic's pixels."""
    if quadrant not in range(4):
        raise ValueError(f"mosaic quadrant must be 0..3, got {quadrant!r}")
    row, column = divmod(quadrant, 2)
    return np.array([[0.5, 0.0, column * tile_size / 2], [0.0, 0.5, row * tile_size / 2]])


def mosaic_grasps(grasps, quadrant: int, tile_size: int) -> np.ndarray:
    """[N, 5] grasps of a tile -> the same grasps in the mosaic's pixels."""
    grasps = np.asarray(grasps, np.float64)
    if grasps.shape[0] == 0:
        return grasps.reshape(0, 5)
    return np.asarray(geometry.transform_grasps(grasps, quadrant_matrix(quadrant, tile_size)))


def _instruction(views: Sequence[View], target: int, kind: str, position_mode: str, tile_size: int) -> str:
    view = views[target]
    if kind != "position":
        return object_sentence(view.words, kind, view.photo_id)
    if position_mode == "quadrant":
        return position_sentence(position_words.quadrant_word(target))
    moved = mosaic_grasps(view.grasps, target, tile_size)
    return position_sentence(position_words.position_word(moved, tile_size, tile_size))


def mosaic_sample(
    views: Sequence[View], target: int, kind: str, position_mode: str = "quadrant", redraws: int = 0
) -> Sample:
    """The MULTI sample of four views in quadrant order whose instruction refers to views[target]."""
    kind = check_kind(kind, MULTI_KINDS, "a multi-object mosaic")
    if position_mode not in POSITION_MODES:
        raise ValueError(f"unknown position_mode {position_mode!r}; expected one of {POSITION_MODES}")
    if len(views) != 4:
        raise ValueError(f"a mosaic needs 4 views, got {len(views)}")
    if target not in range(4):
        raise ValueError(f"mosaic target must be a quadrant 0..3, got {target!r}")
    tile_size = int(np.shape(views[0].image)[0])
    if np.asarray(views[target].grasps).shape[0] == 0:
        raise ValueError(f"photo {views[target].photo_id!r} has no grasps; it cannot be a mosaic target")
    return Sample(
        kind=kind,
        scene="multi",
        instruction=_instruction(views, target, kind, position_mode, tile_size),
        answer=ANSWERS[kind],
        image=mosaic_image([v.image for v in views]),
        grasps=mosaic_grasps(views[target].grasps, target, tile_size),
        photo_ids=tuple(v.photo_id for v in views),
        object_ids=tuple(v.object_id for v in views),
        target=target,
        redraws=redraws,
    )


def _same_object(a: View, b: View) -> bool:
    return a.photo_id == b.photo_id or (a.object_id is not None and a.object_id == b.object_id)


def _cell_in_mosaic(view: View, quadrant: int, tile_size: int) -> tuple[int, int] | None:
    if np.asarray(view.grasps).shape[0] == 0:
        return None
    centroid = position_words.grasps_centroid(mosaic_grasps(view.grasps, quadrant, tile_size))
    return position_words.grid_cell(centroid, tile_size, tile_size)


def build_mosaic(
    pool: Sequence[View],
    target: int,
    kind: str,
    rng: np.random.Generator,
    unambiguous: bool = True,
    position_mode: str = "quadrant",
) -> Sample:
    """A MULTI sample about pool[target] with three distractors drawn from `pool`.

    The target's quadrant is drawn uniformly; the distractors fill the other quadrants in order.
    With `unambiguous=True` a candidate is re-drawn when it is the same object as the target
    (same photo or object id) for a word kind, when its words clash (`distractors.words_clash`),
    or, in cell mode, when its grasps' centroid falls in the target's cell. `Sample.redraws`
    counts the re-draws.
    """
    kind = check_kind(kind, MULTI_KINDS, "a multi-object mosaic")
    if position_mode not in POSITION_MODES:
        raise ValueError(f"unknown position_mode {position_mode!r}; expected one of {POSITION_MODES}")
    target_view = pool[target]
    if kind != "position":
        require(target_view.words, kind, target_view.photo_id)
    quadrant = int(rng.integers(4))
    free = [q for q in range(4) if q != quadrant]
    tile_size = int(np.shape(target_view.image)[0])
    target_cell = _cell_in_mosaic(target_view, quadrant, tile_size) if position_mode == "cell" else None

    def clash(candidate: int, slot: int) -> bool:
        view = pool[candidate]
        if kind == "position":
            return position_mode == "cell" and _cell_in_mosaic(view, free[slot], tile_size) == target_cell
        return _same_object(view, target_view) or distractor_choice.words_clash(target_view.words, view.words, kind)

    draw = distractor_choice.draw_distractors(
        len(pool), target, rng, clash, 3, unambiguous, f"(photo {target_view.photo_id!r}, kind {kind!r})"
    )
    views: list[View] = [target_view] * 4
    for slot, candidate in zip(free, draw.chosen):
        views[slot] = pool[candidate]
    return mosaic_sample(views, quadrant, kind, position_mode, draw.redraws)
