"""The grasp as text: the four representations of the paper's ablation, to text and back.

XYA (KOSMOS-E's own):  "Grasp center point coordinates: x_{x},y_{y} Grasp rotation angle in radians: a_{k}"
XYWHA:                 adds " Grasp width and height: w_{w},h_{h}" after the centre
TLBRA:                 "Grasp bounding box: x_{x1},y_{y1},x_{x2},y_{y2}" (axis-aligned box of the rectangle)
TLBRA-patch:           "Grasp bounding box: <patch_index_{ul}><patch_index_{lr}>" on a 32x32 grid

Pixel values are integers in the `image_size` image. With the angle code off, the angle is written
in radians with two decimals ("a_-0.52"). Parsers never raise: they return a `ParsedGrasp` whose
`ok` is False and whose `error` says why.
"""

from __future__ import annotations

import dataclasses
import math
import re

import numpy as np

from kosmos_jax import geometry

REPRESENTATIONS = ("xya", "xywha", "tlbra", "tlbra_patch")
PATCH_GRID = 32

CENTRE_TEXT = "Grasp center point coordinates: x_{x},y_{y}"
SIZE_TEXT = "Grasp width and height: w_{w},h_{h}"
BOX_TEXT = "Grasp bounding box: x_{x1},y_{y1},x_{x2},y_{y2}"
PATCH_TEXT = "Grasp bounding box: <patch_index_{ul:04d}><patch_index_{lr:04d}>"
ANGLE_TEXT = "Grasp rotation angle in radians: a_{a}"

_INT = r"(-?\d+)"
_NUM = r"(-?\d+(?:\.\d+)?)"
_CENTRE_RE = re.compile(r"Grasp center point coordinates: x_" + _INT + r",y_" + _INT)
_SIZE_RE = re.compile(r"Grasp width and height: w_" + _INT + r",h_" + _INT)
_BOX_RE = re.compile(r"Grasp bounding box: x_" + _INT + r",y_" + _INT + r",x_" + _INT + r",y_" + _INT)
_PATCH_RE = re.compile(r"Grasp bounding box: <patch_index_(\d{4})><patch_index_(\d{4})>")
_ANGLE_RE = re.compile(r"Grasp rotation angle in radians: a_" + _NUM)


@dataclasses.dataclass(frozen=True)
class ParsedGrasp:
    """A parsed answer: `grasp` is (x, y, w, h, theta) with NaN where the text says nothing."""

    ok: bool
    grasp: np.ndarray
    error: str = ""


def _failure(reason: str) -> ParsedGrasp:
    return ParsedGrasp(False, np.full(5, np.nan), reason)


def check_representation(representation: str) -> str:
    if representation not in REPRESENTATIONS:
        raise ValueError(f"unknown grasp representation {representation!r}; expected one of {REPRESENTATIONS}")
    return representation


def format_angle(theta: float, angle_code: bool = True) -> str:
    if angle_code:
        return ANGLE_TEXT.format(a=int(geometry.encode_angle(np.float64(theta))))
    return ANGLE_TEXT.format(a=f"{float(geometry.normalize_angle(np.float64(theta))):.2f}")


def format_centre(grasp) -> str:
    return CENTRE_TEXT.format(x=int(round(float(grasp[0]))), y=int(round(float(grasp[1]))))


def bounding_box(grasp) -> np.ndarray:
    """(x1, y1, x2, y2) of the axis-aligned box around the rotated rectangle."""
    corners = geometry.grasps_to_corners(np.asarray(grasp, np.float64))
    return np.concatenate([corners.min(axis=0), corners.max(axis=0)])


def patch_indices(box, image_size: int) -> tuple[int, int]:
    """KOSMOS-2 patch indices of a box's corners on the 32x32 grid (DESIGN section 2)."""
    x1, y1, x2, y2 = np.clip(np.asarray(box, np.float64) / image_size, 0.0, 1.0)
    last = PATCH_GRID - 1
    ul = min(math.floor(y1 * PATCH_GRID), last) * PATCH_GRID + min(math.floor(x1 * PATCH_GRID), last)
    lr = max(math.ceil(y2 * PATCH_GRID - 1), 0) * PATCH_GRID + max(math.ceil(x2 * PATCH_GRID - 1), 0)
    return ul, lr


def format_grasp(grasp, representation: str = "xya", angle_code: bool = True, image_size: int = 224) -> str:
    """The target text of one grasp (x, y, w, h, theta) in pixels of an `image_size` image."""
    check_representation(representation)
    grasp = np.asarray(grasp, np.float64)
    if representation == "xya":
        location = format_centre(grasp)
    elif representation == "xywha":
        size = SIZE_TEXT.format(w=int(round(grasp[2])), h=int(round(grasp[3])))
        location = format_centre(grasp) + " " + size
    elif representation == "tlbra":
        x1, y1, x2, y2 = (int(round(v)) for v in bounding_box(grasp))
        location = BOX_TEXT.format(x1=x1, y1=y1, x2=x2, y2=y2)
    else:
        ul, lr = patch_indices(bounding_box(grasp), image_size)
        location = PATCH_TEXT.format(ul=ul, lr=lr)
    return location + " " + format_angle(grasp[4], angle_code)


def parse_angle(text: str, angle_code: bool = True) -> tuple[float, str]:
    """(theta, "") from the angle part of an answer, or (nan, reason)."""
    match = _ANGLE_RE.search(text)
    if match is None:
        return math.nan, "no rotation angle"
    value = float(match.group(1))
    if angle_code:
        if not value.is_integer() or not 0 <= value < geometry.ANGLE_BINS:
            return math.nan, f"angle code {match.group(1)} outside 0..{geometry.ANGLE_BINS - 1}"
        return float(geometry.decode_angle(np.int64(value))), ""
    if not -math.pi / 2 <= value <= math.pi / 2:
        return math.nan, f"angle {value} outside [-pi/2, pi/2]"
    return float(geometry.normalize_angle(np.float64(value))), ""


def _box_to_grasp_size(box, theta: float) -> tuple[float, float]:
    """Recover w, h from the axis-aligned box of a rectangle at angle theta (NaN near 45 degrees)."""
    width, height = box[2] - box[0], box[3] - box[1]
    c, s = abs(math.cos(theta)), abs(math.sin(theta))
    det = c * c - s * s
    if abs(det) < 1e-3:
        return math.nan, math.nan
    w = (c * width - s * height) / det
    h = (c * height - s * width) / det
    if w < 0 or h < 0:
        return math.nan, math.nan
    return w, h


def parse_grasp(text: str, representation: str = "xya", angle_code: bool = True, image_size: int = 224) -> ParsedGrasp:
    """Parse an answer. Unknown parts of the grasp (w, h in XYA) are NaN. Never raises on bad text."""
    check_representation(representation)
    if not isinstance(text, str):
        return _failure(f"answer is {type(text).__name__}, not text")
    theta, why = parse_angle(text, angle_code)
    if why:
        return _failure(why)
    w = h = math.nan
    if representation in ("xya", "xywha"):
        match = _CENTRE_RE.search(text)
        if match is None:
            return _failure("no centre point")
        x, y = float(match.group(1)), float(match.group(2))
        if representation == "xywha":
            size = _SIZE_RE.search(text)
            if size is None:
                return _failure("no width and height")
            w, h = float(size.group(1)), float(size.group(2))
            if w <= 0 or h <= 0 or w > 2 * image_size or h > 2 * image_size:
                return _failure(f"width/height {w:g},{h:g} out of range")
    elif representation == "tlbra":
        match = _BOX_RE.search(text)
        if match is None:
            return _failure("no bounding box")
        box = np.array([float(v) for v in match.groups()])
        if box[2] < box[0] or box[3] < box[1]:
            return _failure("bounding box corners in the wrong order")
        if box.min() < -image_size or box.max() > 2 * image_size:
            return _failure(f"bounding box {box.tolist()} far outside the {image_size} image")
        x, y = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
        w, h = _box_to_grasp_size(box, theta)
    else:
        match = _PATCH_RE.search(text)
        if match is None:
            return _failure("no patch-index box")
        ul, lr = int(match.group(1)), int(match.group(2))
        if max(ul, lr) >= PATCH_GRID * PATCH_GRID:
            return _failure(f"patch index above {PATCH_GRID * PATCH_GRID - 1}")
        cell = image_size / PATCH_GRID
        box = np.array([ul % PATCH_GRID, ul // PATCH_GRID, lr % PATCH_GRID, lr // PATCH_GRID], np.float64)
        box = (box + 0.5) * cell  # patch centres, as KOSMOS-2 decodes its boxes
        if box[2] < box[0] or box[3] < box[1]:
            return _failure("patch indices in the wrong order")
        x, y = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
    if not (0 <= x < image_size and 0 <= y < image_size):
        return _failure(f"centre ({x:g}, {y:g}) outside the {image_size} image")
    return ParsedGrasp(True, np.array([x, y, w, h, theta], np.float64))
