"""Reader for the Cornell grasping dataset (and anything written in its file format).

Layout: a root holding numbered folders (`01` .. `10`) or a flat folder, with per photo
`pcdNNNNr.png` (RGB), optional `pcdNNNNd.tiff` (float depth), `pcdNNNNcpos.txt` (positive
rectangles) and `pcdNNNNcneg.txt` (negative rectangles). A photo exists when its `r.png` or its
`cpos.txt` exists; a missing `cpos.txt` / `cneg.txt` means no rectangles of that kind.

Rectangle files: one corner `x y` per line, 4 lines a rectangle, corners in order p0..p3 with
p0 -> p1 the opening (geometry.corners_to_grasps). Blank lines are skipped; CRLF, CR or mixed line
endings (and only those end a line), trailing spaces or tabs, a UTF-8 byte-order mark and a
missing final newline are all accepted. Numbers are ASCII decimals or NaN ('1_0' is not one). A
rectangle with any NaN coordinate is dropped whole and counted (Photo.nan_dropped for cpos.txt).
A line count that is not a multiple of 4, a line that is not two numbers, an infinite number,
bytes that are not UTF-8 or an undecodable image raise CornellFormatError, whose message names
the file (and the line, for text files).

Photos come sorted by id, which is the order KOSMOS-E's annotation keys follow. With
`load_images=False` the Photo's `rgb` and `depth` are None (only labels are read); Photo.height and
Photo.width then do not work.

    python -m kosmos_jax.sources.cornell ROOT [--noimages] [--kosmos_e=PATH]

prints a JSON summary of the data set under ROOT.
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
import re
import sys
from typing import Iterable, Iterator, Sequence

import cv2
import numpy as np
from absl import flags

from kosmos_jax import commands, geometry
from kosmos_jax.sources import kosmos_e_annotations, objects, text_file
from kosmos_jax.sources.cornell_set import FULL_SET_IDS
from kosmos_jax.sources.photo import Photo

FILE_PATTERN = re.compile(r"^(pcd\d{4})(r\.png|d\.tiff|cpos\.txt|cneg\.txt)$")
FOLDER_PATTERN = re.compile(r"\d\d")  # the numbered folders 01 .. 10 (use fullmatch)



class CornellFormatError(ValueError):
    """A Cornell file that cannot be read; the message names the file (and line)."""


@dataclasses.dataclass(frozen=True)
class CornellFiles:
    """The files of one photo; None where the file does not exist."""

    id: str
    rgb: pathlib.Path | None
    depth: pathlib.Path | None
    positives: pathlib.Path | None
    negatives: pathlib.Path | None


_SUFFIX_FIELD = {"r.png": "rgb", "d.tiff": "depth", "cpos.txt": "positives", "cneg.txt": "negatives"}


def find_photos(root: str | pathlib.Path) -> list[CornellFiles]:
    """The photos under `root` (flat, or in two-digit folders), sorted by id; decodes nothing."""
    root = pathlib.Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"Cornell root {root} is not a directory")
    found: dict[str, dict[str, pathlib.Path]] = {}
    folders = [root] + sorted(p for p in root.iterdir() if p.is_dir() and FOLDER_PATTERN.fullmatch(p.name))
    for folder in folders:
        for path in sorted(folder.iterdir()):
            match = FILE_PATTERN.match(path.name)
            if not match or not path.is_file():
                continue
            photo_id, suffix = match.groups()
            fields = found.setdefault(photo_id, {})
            field = _SUFFIX_FIELD[suffix]
            if field in fields:
                raise CornellFormatError(f"photo {photo_id} appears twice: {fields[field]} and {path}")
            fields[field] = path
    photos = []
    for photo_id in sorted(found):
        fields = found[photo_id]
        if "rgb" not in fields and "positives" not in fields:
            continue  # a depth or cneg file alone is not a photo
        photos.append(CornellFiles(photo_id, fields.get("rgb"), fields.get("depth"),
                                   fields.get("positives"), fields.get("negatives")))
    return photos


def list_photo_ids(root: str | pathlib.Path) -> list[str]:
    """Sorted photo ids under `root`, without reading any file."""
    return [files.id for files in find_photos(root)]


def parse_corners(text: str, source: str = "<text>") -> np.ndarray:
    """Cornell rectangle text -> [R, 4, 2] float64 corners (NaN kept). Raises CornellFormatError."""
    points, line_numbers = [], []
    for number, line in enumerate(text_file.split_lines(text), start=1):
        fields = text_file.split_fields(line)
        if not fields:
            continue
        shown = line.strip(" \t")
        if len(fields) != 2:
            raise CornellFormatError(f"{source}, line {number}: expected two numbers 'x y', got {shown!r}")
        try:
            x, y = text_file.parse_number(fields[0]), text_file.parse_number(fields[1])
        except ValueError:
            raise CornellFormatError(f"{source}, line {number}: not a number in {shown!r}") from None
        if math.isinf(x) or math.isinf(y):
            raise CornellFormatError(f"{source}, line {number}: infinite coordinate in {shown!r}")
        points.append((x, y))
        line_numbers.append(number)
    if len(points) % 4:
        first = line_numbers[len(points) - len(points) % 4]
        raise CornellFormatError(
            f"{source}, line {first}: {len(points)} corner lines is not a multiple of 4 "
            f"(incomplete rectangle starts at line {first})")
    return np.asarray(points, np.float64).reshape(-1, 4, 2)


def read_rectangles(path: str | pathlib.Path | None) -> tuple[np.ndarray, int]:
    """A cpos/cneg file -> ([N, 5] grasps without NaN rectangles, number of NaN rectangles dropped)."""
    if path is None:
        return np.zeros((0, 5)), 0
    path = pathlib.Path(path)
    corners = parse_corners(text_file.read_text(path, CornellFormatError), str(path))
    has_nan = np.isnan(corners).any(axis=(1, 2))
    return geometry.corners_to_grasps(corners[~has_nan]).reshape(-1, 5), int(has_nan.sum())


def format_rectangles(grasps: np.ndarray) -> str:
    """[N, 5] grasps -> Cornell rectangle text (the inverse of parse_corners + corners_to_grasps)."""
    corners = geometry.grasps_to_corners(np.asarray(grasps, np.float64).reshape(-1, 5))
    return "".join(f"{float(x)!r} {float(y)!r}\n" for x, y in corners.reshape(-1, 2).tolist())


def write_rectangles(path: str | pathlib.Path, grasps: np.ndarray) -> None:
    pathlib.Path(path).write_text(format_rectangles(grasps))


def read_rgb(path: pathlib.Path) -> np.ndarray:
    """[H, W, 3] uint8 RGB; CornellFormatError naming the file when it cannot be decoded."""
    data = np.fromfile(path, np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if image is None:
        raise CornellFormatError(f"{path}: cannot decode image (corrupt or not an image)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def read_depth(path: pathlib.Path) -> np.ndarray:
    """[H, W] float32 depth from a TIFF; CornellFormatError naming the file when unreadable."""
    data = np.fromfile(path, np.uint8)
    depth = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if depth is None or depth.ndim != 2:
        raise CornellFormatError(f"{path}: cannot decode a single-channel depth image")
    return depth.astype(np.float32)


def read_photo(files: CornellFiles, *, load_images: bool = True,
               object_map: objects.ObjectMap | None = None) -> Photo:
    """One photo's files -> Photo (grasps in photo pixels, file order)."""
    grasps, nan_dropped = read_rectangles(files.positives)
    negatives, _ = read_rectangles(files.negatives)
    rgb = depth = None
    if load_images:
        if files.rgb is None:
            raise CornellFormatError(f"photo {files.id}: no {files.id}r.png beside {files.positives}")
        rgb = read_rgb(files.rgb)
        if files.depth is not None:
            depth = read_depth(files.depth)
            if depth.shape != rgb.shape[:2]:
                raise CornellFormatError(
                    f"{files.depth}: depth shape {depth.shape} differs from image shape {rgb.shape[:2]}")
    object_id = category = None
    if object_map is not None and files.id in object_map:
        object_id, category = object_map[files.id]
    return Photo(id=files.id, rgb=rgb, depth=depth, grasps=grasps, negatives=negatives,
                 object_id=object_id, category=category, nan_dropped=nan_dropped)


def object_map_path(root: pathlib.Path, object_map) -> pathlib.Path | None:
    """The z.txt that `object_map` ("auto", a path, a mapping or None) refers to, if a file."""
    if isinstance(object_map, str) and object_map == "auto":
        return objects.find_object_map(root)
    if isinstance(object_map, (str, pathlib.Path)):
        return pathlib.Path(object_map)
    return None


def resolve_object_map(root: pathlib.Path, object_map) -> objects.ObjectMap | None:
    """"auto": the z.txt found under root (or None); a path: read it; a mapping or None: as is."""
    if isinstance(object_map, (str, pathlib.Path)):
        path = object_map_path(root, object_map)
        return objects.read_object_map(path) if path is not None else None
    return object_map


def iter_photos(root: str | pathlib.Path, *, load_images: bool = True, object_map="auto",
                ids: Iterable[str] | None = None, progress: bool = False) -> Iterator[Photo]:
    """Photos under `root`, sorted by id, read one at a time (lazy)."""
    root = pathlib.Path(root)
    mapping = resolve_object_map(root, object_map)
    all_files = find_photos(root)
    if ids is not None:
        wanted = set(ids)
        missing = wanted - {files.id for files in all_files}
        if missing:
            raise KeyError(f"photos not found under {root}: {sorted(missing)}")
        all_files = [files for files in all_files if files.id in wanted]
    for index, files in enumerate(all_files):
        if progress and (index % 50 == 0 or index == len(all_files) - 1):
            print(f"reading {files.id} ({index + 1}/{len(all_files)})", file=sys.stderr, flush=True)
        yield read_photo(files, load_images=load_images, object_map=mapping)


def load_photos(root: str | pathlib.Path, **kwargs) -> list[Photo]:
    """All photos under `root` in a list (see iter_photos for the options)."""
    return list(iter_photos(root, **kwargs))


def summarize(root: str | pathlib.Path, *, load_images: bool = True, object_map="auto",
              kosmos_e: str | pathlib.Path | None = None, progress: bool = False) -> dict:
    """Counts over the data set under `root` (what the CLI prints)."""
    root = pathlib.Path(root)
    mapping = resolve_object_map(root, object_map)
    map_path = object_map_path(root, object_map)
    annotations = None
    if kosmos_e is not None:
        annotations = kosmos_e_annotations.read_annotations(kosmos_e)
    photos = kept = dropped = negative = negative_dropped = with_depth = unmapped = 0
    object_ids, categories, shapes = set(), set(), {}
    for photo in iter_photos(root, load_images=load_images, object_map=mapping, progress=progress):
        photos += 1
        kept += len(photo.grasps)
        dropped += photo.nan_dropped
        negative += len(photo.negatives)
        with_depth += photo.depth is not None
        if photo.object_id is None:
            unmapped += 1
        else:
            object_ids.add(photo.object_id)
            categories.add(photo.category)
        if photo.rgb is not None:
            key = "x".join(map(str, photo.rgb.shape))
            shapes[key] = shapes.get(key, 0) + 1
        if annotations is not None:
            annotations.attach(photo)  # raises on a count mismatch
    for files in find_photos(root):
        negative_dropped += read_rectangles(files.negatives)[1]
    summary = {
        "root": str(root),
        "photos": photos,
        "photos_in_full_set": sum(files.id in FULL_SET_IDS for files in find_photos(root)),
        "positive_rectangles": kept,
        "nan_rectangles_dropped": dropped,
        "negative_rectangles": negative,
        "negative_nan_rectangles_dropped": negative_dropped,
        "object_map": str(map_path) if mapping is not None and map_path is not None else None,
        "objects": len(object_ids) if mapping is not None else None,
        "categories": len(categories) if mapping is not None else None,
        "photos_without_object": unmapped if mapping is not None else None,
        "photos_with_depth": with_depth if load_images else None,
        "image_shapes": shapes if load_images else None,
    }
    if annotations is not None:
        summary["kosmos_e_annotated_photos"] = photos
    return summary


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("bool", "images", True, "read the photos too (--noimages: the labels only)")
    define("string", "object_map", "auto", "z.txt path (auto: found under ROOT)")
    define("string", "kosmos_e", None, "instructions-original.json to check alignment")


def main(argv: Sequence[str] | None = None) -> int:
    return commands.run_command(define_flags, summary_command, argv, prog="python -m kosmos_jax.sources.cornell",
                                doc="Summarise a Cornell-format grasp data set (ROOT: a folder with 01..10 "
                                    "sub-folders or pcdNNNN files) as JSON.", positional=("root",))


def summary_command(args) -> int:
    try:
        summary = summarize(args.root, load_images=args.images, object_map=args.object_map,
                            kosmos_e=args.kosmos_e, progress=True)
    except (ValueError, FileNotFoundError, KeyError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
