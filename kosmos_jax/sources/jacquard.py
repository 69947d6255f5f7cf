"""Reader for the Jacquard grasping dataset.

Files per photo `<n>_<object>_RGB.png`, `_mask.png`, `_perfect_depth.tiff`, `_stereo_depth.tiff`
and `_grasps.txt`, usually in one folder per object. A grasp line is `x;y;theta_deg;opening;jaw`
(CRLF line endings in the official files). The photo id is `<n>_<object>`; Photo.object_id is the
object's hash string (Photo's hint says int; Jacquard's ids are hex names, kept as str).

Convention, as checked on the sample files (tests/test_jacquard.py measures it):
- x is the column and y the row, as in our (x, y): every grasp centre lies on the object mask
  with (x, y) read that way, against about 10% of them with the two swapped.
- theta is in degrees and positive CLOCKWISE on screen (image y down), the opposite sense of ours,
  so ours = -radians(theta). Evidence: a parallel-jaw grasp sits in the middle of the object along
  its opening axis (the jaws close symmetrically); measured as the distance from the grasp centre
  to the midpoint of the mask chord along the opening axis, the negated angle gives a median of
  1.0 px over the 118 distinct grasps against 2.0 px for the other sign (nearer for 61% of them,
  farther for 29%), and 0.4 - 1.25 px against 3.4 - 3.9 px on each view of the elongated object
  (the other object is a ball, where the two signs are indistinguishable). GG-CNN's loader (`-theta / 180 * pi`) and its Jacquard
  writer (`-angle * 180 / pi`), used for scoring on the Jacquard server, agree.
- opening is our w (the gripper's opening, along the closing axis), jaw our h (the jaw size).
  Jacquard lists the same position with several jaw sizes as separate lines; all are kept.

With `load_images=False` rgb and depth are None. `depth` picks "perfect" or "stereo" depth.
"""

from __future__ import annotations

import dataclasses
import math
import pathlib
import re
import sys
from typing import Iterator

import cv2
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.sources import text_file
from kosmos_jax.sources.photo import Photo

GRASPS_PATTERN = re.compile(r"^(\d+)_(.+)_grasps\.txt$")


class JacquardFormatError(ValueError):
    """A Jacquard file that cannot be read; the message names the file (and line)."""


@dataclasses.dataclass(frozen=True)
class JacquardFiles:
    id: str
    object_id: str
    grasps: pathlib.Path

    def sibling(self, suffix: str) -> pathlib.Path:
        return self.grasps.with_name(f"{self.id}_{suffix}")

    @property
    def rgb(self) -> pathlib.Path:
        return self.sibling("RGB.png")

    @property
    def mask(self) -> pathlib.Path:
        return self.sibling("mask.png")

    def depth(self, kind: str = "perfect") -> pathlib.Path:
        if kind not in ("perfect", "stereo"):
            raise ValueError(f"depth kind {kind!r} must be 'perfect' or 'stereo'")
        return self.sibling(f"{kind}_depth.tiff")


def find_photos(root: str | pathlib.Path) -> list[JacquardFiles]:
    """Every `*_grasps.txt` under `root` (any depth), sorted by photo id; decodes nothing."""
    root = pathlib.Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"Jacquard root {root} is not a directory")
    photos = {}
    for path in sorted(root.rglob("*_grasps.txt")):
        match = GRASPS_PATTERN.match(path.name)
        if not match:
            continue
        photo_id = f"{match.group(1)}_{match.group(2)}"
        if photo_id in photos:
            raise JacquardFormatError(f"photo {photo_id} appears twice: {photos[photo_id].grasps} and {path}")
        photos[photo_id] = JacquardFiles(photo_id, match.group(2), path)
    return [photos[key] for key in sorted(photos)]


def parse_grasp_rows(text: str, source: str = "<text>") -> np.ndarray:
    """Jacquard grasp text -> [N, 5] rows (x, y, theta_deg, opening, jaw) as written."""
    rows = []
    for number, line in enumerate(text_file.split_lines(text), start=1):
        shown = line.strip(" \t")
        if not shown:
            continue
        fields = [field.strip(" \t") for field in shown.split(";")]
        if len(fields) != 5:
            raise JacquardFormatError(f"{source}, line {number}: expected 'x;y;theta;opening;jaw', got {shown!r}")
        try:
            row = [text_file.parse_number(field) for field in fields]
        except ValueError:
            raise JacquardFormatError(f"{source}, line {number}: not a number in {shown!r}") from None
        if not all(math.isfinite(value) for value in row):
            raise JacquardFormatError(f"{source}, line {number}: non-finite value in {shown!r}")
        rows.append(row)
    return np.asarray(rows, np.float64).reshape(-1, 5)


def rows_to_grasps(rows: np.ndarray) -> np.ndarray:
    """[N, 5] Jacquard rows -> [N, 5] our grasps (x, y, w=opening, h=jaw, theta = -radians(deg))."""
    rows = np.asarray(rows, np.float64)
    theta = geometry.normalize_angle(-np.radians(rows[..., 2]))
    return np.stack([rows[..., 0], rows[..., 1], rows[..., 3], rows[..., 4], theta], axis=-1)


def grasps_to_rows(grasps: np.ndarray) -> np.ndarray:
    """Inverse of rows_to_grasps (theta in degrees, in (-90, 90])."""
    grasps = np.asarray(grasps, np.float64)
    return np.stack([grasps[..., 0], grasps[..., 1], -np.degrees(grasps[..., 4]),
                     grasps[..., 2], grasps[..., 3]], axis=-1)


def read_grasps(path: str | pathlib.Path) -> np.ndarray:
    path = pathlib.Path(path)
    return rows_to_grasps(parse_grasp_rows(text_file.read_text(path, JacquardFormatError), str(path)))


def _decode(path: pathlib.Path, flags: int) -> np.ndarray:
    if not path.is_file():
        raise JacquardFormatError(f"{path}: file not found")
    data = np.fromfile(path, np.uint8)
    image = cv2.imdecode(data, flags) if data.size else None
    if image is None:
        raise JacquardFormatError(f"{path}: cannot decode image (corrupt or not an image)")
    return image


def read_mask(files: JacquardFiles) -> np.ndarray:
    """[H, W] bool object mask."""
    return _decode(files.mask, cv2.IMREAD_GRAYSCALE) > 0


def read_photo(files: JacquardFiles, *, load_images: bool = True, depth: str = "perfect") -> Photo:
    grasps = read_grasps(files.grasps)
    rgb = depth_image = None
    if load_images:
        rgb = cv2.cvtColor(_decode(files.rgb, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
        depth_path = files.depth(depth)
        if depth_path.is_file():
            depth_image = _decode(depth_path, cv2.IMREAD_UNCHANGED).astype(np.float32)
            if depth_image.shape != rgb.shape[:2]:
                raise JacquardFormatError(f"{depth_path}: shape {depth_image.shape} differs from the image's {rgb.shape[:2]}")
    return Photo(id=files.id, rgb=rgb, depth=depth_image, grasps=grasps, object_id=files.object_id)


def iter_photos(root: str | pathlib.Path, *, load_images: bool = True, depth: str = "perfect",
                progress: bool = False) -> Iterator[Photo]:
    """Photos under `root`, sorted by id, read one at a time."""
    all_files = find_photos(root)
    for index, files in enumerate(all_files):
        if progress and index % 50 == 0:
            print(f"reading {files.id} ({index + 1}/{len(all_files)})", file=sys.stderr, flush=True)
        yield read_photo(files, load_images=load_images, depth=depth)


def load_photos(root: str | pathlib.Path, **kwargs) -> list[Photo]:
    return list(iter_photos(root, **kwargs))
