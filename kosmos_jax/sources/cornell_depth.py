"""Depth images from the Cornell point clouds, made the way GG-CNN's generate_cornell_depth.py does.

Cornell ships a point cloud `pcdNNNN.txt` per photo: PCD v0.7 ASCII, a header then one point a line
with fields `x y z rgb index`, coordinates in millimetres and `index` = row * 640 + column of the
pixel the point was seen at. The depth this project reads (`pcdNNNNd.tiff`, cornell.read_depth) is
GG-CNN's: float32 [480, 640], per pixel its point's distance from the camera sqrt(x² + y² + z²)
divided by 1000 (metres), 0 where no point fell, then those zeros inpainted with OpenCV's
Navier-Stokes method (radius 1). Unlike GG-CNN, a pixel that has a point keeps its distance rounded
once to float32 (GG-CNN's divide-and-multiply around cv2.inpaint may move it by an ulp or two), and
a NaN or infinite point counts as missing (in GG-CNN it would spoil the whole image). On a repeated
index the last point wins, as in GG-CNN's line-by-line loop.

    python -m kosmos_jax.sources.cornell_depth ROOT [--overwrite]

writes `pcdNNNNd.tiff` beside every `pcdNNNN.txt` under ROOT (at any depth), keeping existing ones
unless --overwrite; a file that cannot be read stops it with one line naming the file (exit 1).
"""

from __future__ import annotations

import os
import pathlib
import re
import sys
from typing import Sequence

import cv2
import numpy as np
import tifffile
from absl import flags

from kosmos_jax import commands
from kosmos_jax.sources import text_file
from kosmos_jax.sources.cornell import CornellFormatError

SHAPE = (480, 640)  # Cornell's images; `index` counts pixels row by row over this width
METRES_PER_UNIT = 1e-3  # Cornell's coordinates are millimetres; the d.tiff holds metres
POINT_CLOUD_NAME = re.compile(r"pcd\d{4}\.txt")  # not the pcdNNNNcpos.txt / cneg.txt rectangles
HEADER_KEYS = ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA")


def _error(path, number, message) -> CornellFormatError:
    return CornellFormatError(f"{path}, line {number}: {message}" if number else f"{path}: {message}")


def _read_header(path, lines: list[str]) -> tuple[dict[str, list[str]], int]:
    """The header's keys -> values, and the index of the first line after DATA."""
    header: dict[str, list[str]] = {}
    for position, line in enumerate(lines):
        fields = text_file.split_fields(line)
        if not fields or fields[0].startswith("#"):
            continue
        if fields[0] not in HEADER_KEYS:
            raise _error(path, position + 1, f"not a PCD header line: {line.strip()[:60]!r} "
                                             f"(expected {', '.join(HEADER_KEYS)})")
        header[fields[0]] = fields[1:]
        if fields[0] == "DATA":
            if fields[1:] != ["ascii"]:
                raise _error(path, position + 1, f"DATA {' '.join(fields[1:])}: only ascii PCD is read")
            return header, position + 1
    raise _error(path, None, "not a PCD file: no DATA line ends a header")


def _header_count(path, header, key) -> int | None:
    if key not in header:
        return None
    values = header[key]
    if len(values) != 1 or not text_file.is_ascii_integer(values[0]):
        raise _error(path, None, f"{key} {' '.join(values)} is not a count")
    return int(values[0])


def _columns(path, header) -> tuple[list[int], int, int]:
    """Columns of x, y, z, the column of index, and the number of columns a point line has."""
    fields = header.get("FIELDS")
    if not fields or not {"x", "y", "z", "index"} <= set(fields):
        raise _error(path, None, f"FIELDS {' '.join(fields or ['missing'])}: needs x y z ... index")
    counts = header.get("COUNT", ["1"] * len(fields))
    if len(counts) != len(fields) or not all(map(text_file.is_ascii_integer, counts)):
        raise _error(path, None, f"COUNT {' '.join(counts)} does not match FIELDS {' '.join(fields)}")
    starts = dict(zip(fields, np.cumsum([0] + [int(c) for c in counts[:-1]]).tolist()))
    return [starts["x"], starts["y"], starts["z"]], starts["index"], sum(int(c) for c in counts)


def _first_bad_line(path, lines, numbers, width) -> CornellFormatError:
    for line, number in zip(lines, numbers):
        fields = text_file.split_fields(line)
        if len(fields) != width:
            return _error(path, number, f"expected {width} values a point, got {len(fields)}")
        try:
            [text_file.parse_number(field) for field in fields]
        except ValueError:
            return _error(path, number, f"not a number in {line.strip()[:60]!r}")
    return _error(path, None, "unreadable point lines")


def read_pcd(path: str | pathlib.Path, shape: tuple[int, int] = SHAPE) -> tuple[np.ndarray, np.ndarray]:
    """An ASCII PCD file -> (points [N, 3] float32, pixel index [N] int64 within a `shape` image).

    CornellFormatError naming the file (and line) on a missing or wrong header, fewer or more point
    lines than POINTS (or WIDTH x HEIGHT) says, a malformed point line or an index outside the image.
    """
    path = pathlib.Path(path)
    lines = text_file.split_lines(text_file.read_text(path, CornellFormatError))
    header, data_start = _read_header(path, lines)
    xyz, index_column, width = _columns(path, header)
    announced = _header_count(path, header, "POINTS")
    grid, height = _header_count(path, header, "WIDTH"), _header_count(path, header, "HEIGHT")
    if grid is not None and height is not None:
        grid *= height
    if announced is None and grid is None:
        raise _error(path, None, "the header has neither POINTS nor WIDTH")
    if announced is not None and grid is not None and announced != grid:
        raise _error(path, None, f"POINTS {announced} differs from WIDTH x HEIGHT = {grid}")
    expected = announced if announced is not None else grid
    numbers = [n for n in range(data_start + 1, len(lines) + 1) if lines[n - 1].strip(" \t")]
    data = [lines[n - 1] for n in numbers]
    if len(data) != expected:
        problem = "truncated" if len(data) < expected else "too long"
        raise _error(path, None, f"{problem}: {len(data)} point lines, the header says {expected}")
    try:
        values = np.loadtxt(data, dtype=np.float64, comments=None, ndmin=2) if data else np.zeros((0, width))
    except ValueError:
        raise _first_bad_line(path, data, numbers, width) from None
    if values.shape[1] != width:
        raise _first_bad_line(path, data, numbers, width)
    index = values[:, index_column]
    bad = ~((index >= 0) & (index < shape[0] * shape[1]) & (index == np.floor(index)))
    if bad.any():
        first = int(np.argmax(bad))
        raise _error(path, numbers[first], f"pixel index {data[first].split()[index_column]} "
                                           f"is not a pixel of the {shape[0]}x{shape[1]} image")
    return values[:, xyz].astype(np.float32), index.astype(np.int64)


def depth_image(points: np.ndarray, index: np.ndarray, shape: tuple[int, int] = SHAPE,
                metres_per_unit: float = METRES_PER_UNIT) -> np.ndarray:
    """[H, W] float32: each point's distance from the origin (times metres_per_unit) at its pixel,
    0 where no point fell (or its distance is not finite)."""
    index = np.asarray(index, np.int64)
    if index.size and (index.min() < 0 or index.max() >= shape[0] * shape[1]):
        raise ValueError(f"pixel index outside the {shape[0]}x{shape[1]} image")
    distance = np.sqrt(np.square(np.asarray(points, np.float64)).sum(axis=1)) * metres_per_unit
    # numpy leaves the winner of a repeated index unspecified; keep each pixel's last point
    _, from_end = np.unique(index[::-1], return_index=True)
    last = index.size - 1 - from_end
    flat = np.zeros(shape[0] * shape[1], np.float32)
    flat[index[last]] = np.where(np.isfinite(distance[last]), distance[last], 0.0)
    return flat.reshape(shape)


def inpaint_missing(depth: np.ndarray) -> np.ndarray:
    """`depth` with its 0, NaN and infinite pixels filled by OpenCV's Navier-Stokes inpainting (radius 1);
    the other pixels unchanged. ValueError when no pixel has a depth."""
    depth = np.asarray(depth, np.float32)
    missing = (depth == 0) | ~np.isfinite(depth)
    if missing.all():
        raise ValueError("no pixel has a depth to inpaint from")
    if not missing.any():
        return depth.copy()
    known = np.where(missing, np.float32(0), depth)
    # As GG-CNN: OpenCV inpaints float32 only within [-1, 1], and does not fill up to the image edge
    # without a 1-pixel border (reflected, mask with it).
    scale = float(np.abs(known).max())
    border = dict(top=1, bottom=1, left=1, right=1, borderType=cv2.BORDER_REFLECT_101)
    image = cv2.copyMakeBorder((known / scale).astype(np.float32), **border)
    mask = cv2.copyMakeBorder(missing.astype(np.uint8), **border)
    filled = cv2.inpaint(image, mask, 1, cv2.INPAINT_NS)[1:-1, 1:-1].astype(np.float64) * scale
    return np.where(missing, filled, depth).astype(np.float32)


def depth_path(point_cloud: pathlib.Path) -> pathlib.Path:
    """pcdNNNN.txt -> pcdNNNNd.tiff beside it."""
    return point_cloud.with_name(point_cloud.stem + "d.tiff")


def write_tiff(path: pathlib.Path, image: np.ndarray) -> None:
    """Write to a temporary name then rename, so an interrupted run leaves no partial tiff."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.part")
    try:
        with open(temporary, "wb") as file:
            tifffile.imwrite(file, image, datetime=None, software="kosmos_jax.cornell_depth")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def convert(point_cloud: str | pathlib.Path, *, overwrite: bool = False) -> bool:
    """Write the d.tiff of one point cloud; False when it exists and `overwrite` is not set."""
    point_cloud = pathlib.Path(point_cloud)
    target = depth_path(point_cloud)
    if target.exists() and not overwrite:
        return False
    points, index = read_pcd(point_cloud)
    try:
        depth = inpaint_missing(depth_image(points, index))
    except ValueError as error:
        raise CornellFormatError(f"{point_cloud}: {error}") from None
    write_tiff(target, depth)
    return True


def find_point_clouds(root: str | pathlib.Path) -> list[pathlib.Path]:
    """The pcdNNNN.txt files under `root`, at any depth, sorted; an error when there are none."""
    root = pathlib.Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: not a directory")
    found = sorted(p for p in root.rglob("pcd*.txt") if POINT_CLOUD_NAME.fullmatch(p.name) and p.is_file())
    if not found:
        raise CornellFormatError(f"{root}: no pcdNNNN.txt point clouds under it")
    return found


def define_flags(flag_values: flags.FlagValues) -> None:
    commands.definer(flag_values)("bool", "overwrite", False, "rewrite existing pcdNNNNd.tiff files")


def main(argv: Sequence[str] | None = None) -> int:
    return commands.run_command(define_flags, depth_command, argv, prog="python -m kosmos_jax.sources.cornell_depth",
                                doc="Write GG-CNN's depth images pcdNNNNd.tiff from the Cornell point clouds "
                                    "pcdNNNN.txt under ROOT (in sub-folders or not).", positional=("root",))


def depth_command(args) -> int:
    written = kept = 0
    try:
        clouds = find_point_clouds(args.root)
        for number, cloud in enumerate(clouds, start=1):
            done = convert(cloud, overwrite=args.overwrite)
            written, kept = written + done, kept + (not done)
            print(f"[{number}/{len(clouds)}] {'wrote' if done else 'kept'} {depth_path(cloud)}",
                  file=sys.stderr, flush=True)
    except (CornellFormatError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    print(f"{written} depth images written, {kept} existing kept, "
          f"from {len(clouds)} point clouds under {args.root}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
