"""Grasps drawn on images, the paper's Fig. 7 style: the predicted rectangle in red, the ground
truths in blue, the instruction as a caption under the picture; and grids of such tiles.

Drawn with OpenCV (cv2.polylines, cv2.putText) on RGB uint8 arrays; `write_png` converts to the
BGR order OpenCV's writer expects. Rectangles are (x, y, w, h, theta) in the image's pixels
(DESIGN.md section 2); a tile may be enlarged first (`zoom`) so a 224 view's caption is legible.
"""

from __future__ import annotations

import pathlib
from collections.abc import Sequence

import cv2
import numpy as np

from kosmos_jax import geometry

RED = (255, 0, 0)  # RGB
BLUE = (0, 0, 255)
NO_INSTRUCTION = "(no instruction: NON)"  # the caption of KOSMOS-E's NON kind, whose instruction is empty
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _polygon(grasp, zoom: float) -> np.ndarray:
    corners = np.asarray(geometry.grasps_to_corners(np.asarray(grasp, np.float64)[None]))[0] * zoom
    # polylines takes pixel indices: a corner at x sits at index x - 0.5; fixed point with 4 fraction bits
    return np.round((corners - 0.5) * 16).astype(np.int32)


def draw_grasp(image: np.ndarray, grasp, colour, thickness: int, zoom: float = 1.0) -> None:
    """Draw one rectangle (with a dot at its centre) on `image` in place; NaN grasps are skipped."""
    if not np.isfinite(np.asarray(grasp, np.float64)).all():
        return
    cv2.polylines(image, [_polygon(grasp, zoom)], True, colour, thickness, cv2.LINE_AA, shift=4)
    centre = tuple(int(v) for v in np.round((np.asarray(grasp[:2]) * zoom - 0.5) * 16))
    cv2.circle(image, centre, thickness * 16, colour, -1, cv2.LINE_AA, shift=4)


def _wrapped(text: str, width: int, scale: float, thickness: int) -> list[str]:
    lines, line = [], ""
    for word in text.split():
        candidate = f"{line} {word}".strip()
        if line and cv2.getTextSize(candidate, _FONT, scale, thickness)[0][0] > width:
            lines.append(line)
            candidate = word
        line = candidate
    return lines + [line] if line else lines


def caption_band(text: str, width: int, scale: float) -> np.ndarray:
    """A white band holding `text` in black, wrapped to `width` pixels."""
    thickness = max(1, round(scale * 1.5))
    height = cv2.getTextSize("Ag", _FONT, scale, thickness)[0][1]
    step, margin = int(height * 1.8), max(4, int(height * 0.6))
    lines = _wrapped(text, width - 2 * margin, scale, thickness) or [""]
    band = np.full((2 * margin + step * len(lines), width, 3), 255, np.uint8)
    for number, line in enumerate(lines):
        baseline = margin + height + number * step
        cv2.putText(band, line, (margin, baseline), _FONT, scale, (0, 0, 0), thickness, cv2.LINE_AA)
    return band


def overlay(image: np.ndarray, predicted=None, truths=(), caption: str = "", zoom: float = 1.0) -> np.ndarray:
    """A copy of `image` (RGB uint8), enlarged by `zoom`, with the ground truths [N, 5] in blue, the
    predicted grasp [5] in red on top, and `caption` in a band beneath."""
    picture = np.ascontiguousarray(image, np.uint8)
    if zoom != 1.0:
        picture = cv2.resize(picture, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
    picture = picture.copy()
    thickness = max(1, round(min(picture.shape[:2]) / 200))
    for truth in np.asarray(truths, np.float64).reshape(-1, 5):
        draw_grasp(picture, truth, BLUE, thickness, zoom)
    if predicted is not None:
        draw_grasp(picture, predicted, RED, thickness + 1, zoom)
    if not caption:
        return picture
    return np.concatenate([picture, caption_band(caption, picture.shape[1], picture.shape[1] / 640)], axis=0)


def grid(tiles: Sequence[np.ndarray], columns: int, gap: int = 6) -> np.ndarray:
    """Tiles (RGB uint8, any heights, one width) in rows of `columns`, on white."""
    if not tiles:
        raise ValueError("no tiles to put in a grid")
    columns = max(1, min(columns, len(tiles)))
    width = max(t.shape[1] for t in tiles)
    rows = [tiles[i:i + columns] for i in range(0, len(tiles), columns)]
    heights = [max(t.shape[0] for t in row) for row in rows]
    out = np.full((sum(heights) + gap * (len(rows) + 1), columns * width + gap * (columns + 1), 3), 255, np.uint8)
    top = gap
    for row, height in zip(rows, heights):
        for column, tile in enumerate(row):
            left = gap + column * (width + gap)
            out[top:top + tile.shape[0], left:left + tile.shape[1]] = tile
        top += height + gap
    return out


def write_png(path, image: np.ndarray) -> pathlib.Path:
    path = pathlib.Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(np.ascontiguousarray(image, np.uint8), cv2.COLOR_RGB2BGR)):
        raise OSError(f"{path}: OpenCV could not write the PNG (is the folder writable, the suffix .png?)")
    return path
