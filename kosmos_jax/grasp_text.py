"""The grasp as text: the four representations of the paper's ablation, to text and back.

XYA (KOSMOS-E's own):  "Grasp center point coordinates: x_{x},y_{y} Grasp rotation angle in radians: a_{k}"
XYWHA:                 adds " Grasp width and height: w_{w},h_{h}" after the centre
TLBRA:                 "Grasp bounding box: x_{x1},y_{y1},x_{x2},y_{y2}" (axis-aligned box of the rectangle)
TLBRA-patch:           "Grasp bounding box: <patch_index_{ul}><patch_index_{lr}>" on a 32x32 grid

Pixel values are integers in the `image_size` (S) image, halves rounded up. With the angle code
off, the angle is written in radians with two decimals ("a_-0.52").

Writing keeps every value inside what parsing accepts, so every formatted grasp parses: centres
(and the centre a TLBRA box is built around) are clamped to [0, S-1], XYWHA's w and h to [1, 2S],
box corners to [-S, 2S]. A value the representation needs that is NaN or infinite raises
ValueError naming the grasp.

Parsing is strict about the numbers and lenient about the text around the answer: a number is
ASCII digits (with a '-' and, for radians, decimals) and must end where a non-word, non-dot
character (a space, '<' of `</s>`) or the text ends, so "a_12abc" and "a_12.5" as a code fail;
each field's cue ("Grasp center point coordinates:", ...) must appear exactly once ("more than one
centre point" otherwise). Parsers never raise: they return a `ParsedGrasp` whose `ok` is False
and whose `error` says why.
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

# Numbers end at a non-word, non-dot character: "a_12abc" and "x_1,y_2.5" are not numbers.
_END = r"(?![\w.])"
_INT = r"(-?[0-9]+)"
_NUM = r"(-?[0-9]+(?:\.[0-9]+)?)"
_CENTRE_RE = re.compile(r"Grasp center point coordinates: x_" + _INT + r",y_" + _INT + _END)
_SIZE_RE = re.compile(r"Grasp width and height: w_" + _INT + r",h_" + _INT + _END)
_BOX_RE = re.compile(r"Grasp bounding box: x_" + _INT + r",y_" + _INT + r",x_" + _INT + r",y_" + _INT + _END)
_PATCH_RE = re.compile(r"Grasp bounding box: <patch_index_([0-9]{4})><patch_index_([0-9]{4})>")
_ANGLE_RE = re.compile(r"Grasp rotation angle in radians: a_" + _NUM + _END)


def split_cue(text: str) -> tuple[str, str]:
    """"Grasp center point coordinates: x_1,y_2" -> ("Grasp center point coordinates:", "x_1,y_2")."""
    cue, sep, value = text.partition(": ")
    if not sep:
        raise ValueError(f"grasp text {text!r} has no 'cue: value' form")
    return cue + ":", value


# The fields of each representation: (what, cue, pattern).
_CENTRE = ("centre point", split_cue(CENTRE_TEXT)[0], _CENTRE_RE)
_SIZE = ("width and height", split_cue(SIZE_TEXT)[0], _SIZE_RE)
_BOX = ("bounding box", split_cue(BOX_TEXT)[0], _BOX_RE)
_PATCH = ("patch-index box", split_cue(PATCH_TEXT)[0], _PATCH_RE)
_ANGLE = ("rotation angle", split_cue(ANGLE_TEXT)[0], _ANGLE_RE)
# The values each representation writes: x, y, w, h, theta.
_NEEDED = {"xya": [0, 1, 4], "xywha": [0, 1, 2, 3, 4], "tlbra": [0, 1, 2, 3, 4], "tlbra_patch": [0, 1, 2, 3, 4]}


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


def _pixel(value: float) -> int:
    """The nearest integer, halves rounded up (so a box's rounded ends keep its middle inside)."""
    return math.floor(float(value) + 0.5)


def _clamp(value: int, low: int, high: int) -> int:
    return min(max(value, low), high)


def format_angle(theta: float, angle_code: bool = True) -> str:
    if not math.isfinite(float(theta)):
        raise ValueError(f"cannot write the grasp angle {float(theta)!r} as text: not finite")
    if angle_code:
        return ANGLE_TEXT.format(a=int(geometry.encode_angle(np.float64(theta))))
    return ANGLE_TEXT.format(a=f"{float(geometry.normalize_angle(np.float64(theta))):.2f}")


def format_centre(grasp, image_size: int = 224) -> str:
    """The centre text, each coordinate rounded and clamped to the image's pixels [0, S-1]."""
    x, y = (_clamp(_pixel(v), 0, image_size - 1) for v in grasp[:2])
    return CENTRE_TEXT.format(x=x, y=y)


def bounding_box(grasp) -> np.ndarray:
    """(x1, y1, x2, y2) of the axis-aligned box around the rotated rectangle."""
    corners = geometry.grasps_to_corners(np.asarray(grasp, np.float64))
    return np.concatenate([corners.min(axis=0), corners.max(axis=0)])


def patch_indices(box, image_size: int) -> tuple[int, int]:
    """KOSMOS-2 patch indices of a box's corners on the 32x32 grid (DESIGN section 2)."""
    x1, y1, x2, y2 = np.clip(np.asarray(box, np.float64) / image_size, 0.0, 1.0)
    last = PATCH_GRID - 1
    ul_row, ul_col = min(math.floor(y1 * PATCH_GRID), last), min(math.floor(x1 * PATCH_GRID), last)
    # a box of no width on a grid line would put lr one cell before ul; parsing needs lr >= ul
    lr_row = max(math.ceil(y2 * PATCH_GRID - 1), ul_row)
    lr_col = max(math.ceil(x2 * PATCH_GRID - 1), ul_col)
    return ul_row * PATCH_GRID + ul_col, lr_row * PATCH_GRID + lr_col


def box_text(grasp, image_size: int) -> str:
    """TLBRA's box: the axis-aligned box of the grasp with its centre clamped into the image,
    corners rounded half up (their middle then stays in [0, S-1/2]) and clamped to [-S, 2S]."""
    inside = np.array(grasp, np.float64)
    inside[:2] = np.clip(inside[:2], 0.0, image_size - 1.0)
    x1, y1, x2, y2 = (_clamp(_pixel(v), -image_size, 2 * image_size) for v in bounding_box(inside))
    return BOX_TEXT.format(x1=x1, y1=y1, x2=x2, y2=y2)


def format_grasp(grasp, representation: str = "xya", angle_code: bool = True, image_size: int = 224) -> str:
    """The target text of one grasp (x, y, w, h, theta) in pixels of an `image_size` image."""
    check_representation(representation)
    grasp = np.asarray(grasp, np.float64)
    if grasp.shape != (5,):
        raise ValueError(f"a grasp is (x, y, w, h, theta); got shape {grasp.shape}")
    if not np.isfinite(grasp[_NEEDED[representation]]).all():
        raise ValueError(f"cannot write grasp {grasp.tolist()} as {representation} text: "
                         "a value it needs is not finite")
    if representation == "xya":
        location = format_centre(grasp, image_size)
    elif representation == "xywha":
        w, h = (_clamp(_pixel(v), 1, 2 * image_size) for v in grasp[2:4])
        location = format_centre(grasp, image_size) + " " + SIZE_TEXT.format(w=w, h=h)
    elif representation == "tlbra":
        location = box_text(grasp, image_size)
    else:
        ul, lr = patch_indices(bounding_box(grasp), image_size)
        location = PATCH_TEXT.format(ul=ul, lr=lr)
    return location + " " + format_angle(grasp[4], angle_code)


def _find(text: str, field) -> tuple[re.Match | None, str]:
    """(match, "") of a field that appears exactly once in `text`, or (None, reason)."""
    what, cue, pattern = field
    count = text.count(cue)
    if count != 1:
        return None, f"no {what}" if count == 0 else f"more than one {what} ({count})"
    match = pattern.search(text)
    return (match, "") if match else (None, f"malformed {what}")


def parse_angle(text: str, angle_code: bool = True) -> tuple[float, str]:
    """(theta, "") from the angle part of an answer, or (nan, reason)."""
    match, why = _find(text, _ANGLE)
    if why:
        return math.nan, why
    spelled = match.group(1)
    value = float(spelled)
    if angle_code:
        if "." in spelled or not 0 <= value < geometry.ANGLE_BINS:
            return math.nan, f"angle code {spelled} outside the integers 0..{geometry.ANGLE_BINS - 1}"
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
        match, why = _find(text, _CENTRE)
        if why:
            return _failure(why)
        x, y = float(match.group(1)), float(match.group(2))
        if representation == "xywha":
            size, why = _find(text, _SIZE)
            if why:
                return _failure(why)
            w, h = float(size.group(1)), float(size.group(2))
            if w <= 0 or h <= 0 or w > 2 * image_size or h > 2 * image_size:
                return _failure(f"width/height {w:g},{h:g} out of range")
    elif representation == "tlbra":
        match, why = _find(text, _BOX)
        if why:
            return _failure(why)
        box = np.array([float(v) for v in match.groups()])
        if box[2] < box[0] or box[3] < box[1]:
            return _failure("bounding box corners in the wrong order")
        if box.min() < -image_size or box.max() > 2 * image_size:
            return _failure(f"bounding box {box.tolist()} far outside the {image_size} image")
        x, y = (box[0] + box[2]) / 2, (box[1] + box[3]) / 2
        w, h = _box_to_grasp_size(box, theta)
    else:
        match, why = _find(text, _PATCH)
        if why:
            return _failure(why)
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
