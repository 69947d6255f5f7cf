"""Synthetic grasping scenes written as a Cornell-layout dataset: the project's own data.

    python -m kosmos_jax.sources.synthetic --out DIR --photos N --seed S [--overwrite]

writes, like the real Cornell set (see ../shared/data/README.md):
  DIR/01/pcd0100r.png ...        640x480 RGB photo; 100 photos a folder (01, 02, ..., 10 for pcd1000)
  DIR/01/pcd0100d.tiff           480x640 float32 depth in metres, the GG-CNN-processed convention:
                                 distance from the camera, so objects are SMALLER than the table
                                 (see render.py's docstring)
  DIR/01/pcd0100cpos.txt, cneg.txt  4 lines `x y` a rectangle, p0 -> p1 the opening (DESIGN.md 2)
  DIR/processedData/z.txt        `0100 3 Mug pcdb_0002`, one line a rectangle, as Cornell's
  DIR/processedData/backgroundMapping.txt
  DIR/synthetic_meta.json        per photo: object id, category, name, colour, shape, purpose,
                                 strategy, position, named part polygons, the part of every
                                 positive grasp (cpos.txt order), table depth plane, pose
Every object is seen in several photos (about 3.7, as in Cornell) in different poses. The same
seed gives the same bytes in every file, and photo k does not depend on how many photos follow it.

Writing is atomic (kosmos_jax.publish): the set is made in a hidden sibling folder
(`.staging-DIR-HOST-PID-*`) and renamed to DIR when complete, so a stopped run leaves DIR as it was
(a killed writer's sibling is deleted by the next write). --overwrite replaces only a synthetic set:
a folder that holds synthetic_meta.json, or nothing but the generator's files (what a run of an
older version, which wrote straight into DIR, left when stopped); it keeps the files there that the
generator does not make.

API: plan(seed, photos) -> which object each photo shows; make_scene(rng, spec, background) ->
Scene(rgb, depth, positives, negatives, meta, object_mask); posed_photo(seed, index) -> a written
photo's Scene again and its Posed object, on which draw_positives(rng, posed) draws other annotations
of the same photo; write_dataset(out, photos, seed);
read_meta(root) -> the per-photo metadata (read_header(root): with the set's seed); is_partial_dataset(root) -> whether a folder is what
an interrupted write of older versions (straight into DIR) left behind. Objects:
objects.py; drawing and depth: render.py; grasp rectangles: grasps.py (this package).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import itertools
import json
import math
import os
import pathlib
import re
import sys
import time

import cv2
import numpy as np
import tifffile
from absl import flags

from kosmos_jax import commands, geometry
from kosmos_jax.sources import cornell
from kosmos_jax.sources.synthetic import grasps as grasps_lib
from kosmos_jax.sources.synthetic.objects import CATEGORIES, ObjectSpec, place, pose_matrix, sample_object
from kosmos_jax.sources.synthetic.render import HEIGHT, MIN_OBJECT_HEIGHT_M, WIDTH, Background, make_background, render
from kosmos_jax import publish

FIRST_NUMBER = 100  # Cornell's photos start at pcd0100
MAX_PHOTOS = 9999 - FIRST_NUMBER + 1
# threads drawing photos: `python -m kosmos_jax.sources.synthetic --photos 150` took 4.2 s against 7.1 s on one (2 cores)
WRITERS = min(2, os.cpu_count() or 1)
PHOTOS_PER_OBJECT = ((1, 2, 3, 4, 5), (0.05, 0.05, 0.1, 0.75, 0.05))  # mean 3.7, like Cornell
POSITIVES = ((2, 3, 4, 5, 6, 7), (0.05, 0.2, 0.3, 0.2, 0.15, 0.1))
NEGATIVES = ((0, 1, 2, 3, 4), (0.03, 0.07, 0.2, 0.6, 0.1))
META_NAME = "synthetic_meta.json"
_PROCESSED_FILE = re.compile(r"z\.txt|backgroundMapping\.txt")


@dataclasses.dataclass(frozen=True)
class Scene:
    rgb: np.ndarray  # [480, 640, 3] uint8 RGB
    depth: np.ndarray  # [480, 640] float32 metres
    positives: np.ndarray  # [N, 4, 2] corners, p0 -> p1 the opening
    negatives: np.ndarray  # [K, 4, 2]
    meta: dict
    object_mask: np.ndarray  # [480, 640] bool


@dataclasses.dataclass(frozen=True)
class PlannedPhoto:
    index: int  # 0-based photo index
    object_index: int
    category: str
    background_index: int


def photo_stem(index: int) -> tuple[str, str]:
    """(folder, stem) of the index-th photo: 0 -> ("01", "pcd0100"), 900 -> ("10", "pcd1000")."""
    number = FIRST_NUMBER + index
    return f"{number // 100:02d}", f"pcd{number:04d}"


def plan(seed: int, photos: int) -> list[PlannedPhoto]:
    """Which object (and category, background) each photo shows; a prefix of any longer plan."""
    rng = np.random.default_rng([seed, 0])
    names = sorted(CATEGORIES)
    out, object_index, background_index, round_order = [], 0, 0, []
    objects_on_background = int(rng.integers(2, 5))
    while len(out) < photos:
        if not round_order:  # every category once per round, so a few dozen photos show them all
            round_order = [names[i] for i in rng.permutation(len(names))]
        category = round_order.pop(0)
        count = int(rng.choice(PHOTOS_PER_OBJECT[0], p=PHOTOS_PER_OBJECT[1]))
        if objects_on_background == 0:
            background_index += 1
            objects_on_background = int(rng.integers(2, 5))
        objects_on_background -= 1
        for _ in range(count):
            if len(out) < photos:
                out.append(PlannedPhoto(len(out), object_index, category, background_index))
        object_index += 1
    return out


def position_word(mask: np.ndarray) -> str:
    """KOSMOS-E's nine sections: "top left" ... "middle" ... "bottom right" of the object's centroid."""
    ys, xs = np.nonzero(mask)
    col = min(2, int(3 * (xs.mean() + 0.5) / mask.shape[1]))
    row = min(2, int(3 * (ys.mean() + 0.5) / mask.shape[0]))
    vertical, horizontal = ("top", "", "bottom")[row], ("left", "", "right")[col]
    return " ".join(w for w in (vertical, horizontal) if w) or "middle"


def colour_phrase(colours) -> str:
    if len(colours) == 1:
        return colours[0]
    return f"{colours[0]} with {' and '.join(colours[1:])} details"


def _round(points, digits=2):
    return np.round(np.asarray(points, np.float64), digits).tolist()


def _pose_fits(placed: ObjectSpec, background: Background) -> bool:
    every = np.concatenate([p.shell for p in placed.parts])
    if every[:, 0].min() < 30 or every[:, 0].max() > WIDTH - 30 or every[:, 1].max() > HEIGHT - 30:
        return False
    return bool(grasps_lib.inside(background.table_mask, every).all() and every[:, 1].min() > 40)


@dataclasses.dataclass(frozen=True)
class Posed:
    """A scene's object as placed and drawn, before any grasp is drawn on it."""
    spec: ObjectSpec  # placed in the photo
    masks: grasps_lib.Masks
    graspable: tuple[int, ...]  # the parts with a spine
    chances: np.ndarray  # each graspable part's chance of holding a positive grasp


def draw_positives(rng: np.random.Generator, posed: Posed) -> tuple[list[np.ndarray], list[str]]:
    """One annotation of the posed object: its positive grasps (x, y, w, h, theta) and their parts; 2 to 7 are
    tried, and a try that finds no antipodal grasp on its part adds none (possibly none at all)."""
    positives, parts_of = [], []
    for _ in range(int(rng.choice(POSITIVES[0], p=POSITIVES[1]))):
        k = posed.graspable[int(rng.choice(len(posed.graspable), p=posed.chances))]
        grasp = grasps_lib.sample_positive(rng, posed.spec.parts[k], k, posed.masks)
        if grasp is not None:
            positives.append(grasp)
            parts_of.append(posed.spec.parts[k].name)
    return positives, parts_of


def make_scene(rng: np.random.Generator, spec: ObjectSpec, background: Background, tries: int = 40) -> Scene:
    """Pose `spec` on `background`, render it, and sample its positive and negative grasps."""
    return make_posed_scene(rng, spec, background, tries)[0]


def make_posed_scene(rng: np.random.Generator, spec: ObjectSpec, background: Background,
                     tries: int = 40) -> tuple[Scene, Posed]:
    """make_scene's scene and the posed object its grasps were drawn on (to draw them again)."""
    graspable = tuple(i for i, p in enumerate(spec.parts) if p.spine is not None)
    weights = np.array([spec.parts[i].weight for i in graspable])
    for _ in range(tries):
        angle, scale = rng.uniform(0, 2 * math.pi), rng.uniform(0.9, 1.12)
        centre = rng.uniform([200, 200], [440, 370])
        placed = place(spec, pose_matrix(centre[0], centre[1], angle, scale))
        if not _pose_fits(placed, background):
            continue
        drawn = render(rng, background, placed)
        posed = Posed(placed, grasps_lib.Masks(drawn.object_mask, drawn.part_masks), graspable, weights / weights.sum())
        positives, parts_of = draw_positives(rng, posed)
        if not positives:
            continue
        negatives, kinds = [], []
        for _ in range(int(rng.choice(NEGATIVES[0], p=NEGATIVES[1]))):
            part = placed.parts[graspable[int(rng.integers(len(graspable)))]]
            kind = str(rng.choice(grasps_lib.NEGATIVE_KINDS))
            kind = "narrow" if kind == "along" and part.isotropic else kind
            grasp = grasps_lib.sample_negative(rng, kind, part, posed.masks)
            if grasp is not None:
                negatives.append(grasp)
                kinds.append(kind)
        meta = {
            "object_id": spec.object_id,
            "category": spec.category,
            "name": spec.name,
            "colour": list(spec.colours),
            "colour_phrase": colour_phrase(spec.colours),
            "shape": list(spec.shape_words),
            "shape_phrase": spec.shape_phrase,
            "purpose": spec.purpose,
            "strategy": spec.strategy,
            "position": position_word(drawn.object_mask),
            "parts": [{"name": p.name, "graspable": p.spine is not None, "polygon": _round(p.shell),
                       "holes": [_round(h) for h in p.holes]} for p in placed.parts],
            "grasp_parts": parts_of,
            "negative_kinds": kinds,
            "pose": {"x": round(float(centre[0]), 3), "y": round(float(centre[1]), 3),
                     "angle_deg": round(math.degrees(angle), 3), "scale": round(float(scale), 4)},
            "background": background.name,
            "table_kind": background.kind,
            "table_inverse_depth": list(background.table_inverse_depth),
        }
        to_corners = lambda gs: geometry.grasps_to_corners(np.array(gs, np.float64).reshape(-1, 5))  # noqa: E731
        scene = Scene(rgb=drawn.rgb, depth=drawn.depth, positives=to_corners(positives),
                      negatives=to_corners(negatives), meta=meta, object_mask=drawn.object_mask)
        return scene, posed
    raise RuntimeError(f"could not place a graspable {spec.category} (object {spec.object_id}) in {tries} tries")


# ---- files -----------------------------------------------------------------------------------


def _number(value: float) -> str:
    text = f"{round(float(value), 3):.3f}".rstrip("0").rstrip(".")
    return "0" if text == "-0" else text


def format_rectangles(corners: np.ndarray) -> str:
    """Cornell's text: `x y` a line, trailing space on the first three lines of each rectangle."""
    lines = []
    for rectangle in np.asarray(corners).reshape(-1, 4, 2):
        for k, (x, y) in enumerate(rectangle):
            lines.append(f"{_number(x)} {_number(y)}" + (" " if k < 3 else "") + "\n")
    return "".join(lines)


def write_photo(folder: pathlib.Path, stem: str, scene: Scene) -> None:
    ok, png = cv2.imencode(".png", cv2.cvtColor(scene.rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise RuntimeError(f"PNG encoding failed for {folder / stem}")
    (folder / f"{stem}r.png").write_bytes(png.tobytes())
    # No timestamp (datetime=None), so the same scene gives the same bytes.
    tifffile.imwrite(folder / f"{stem}d.tiff", scene.depth, datetime=None, software="kosmos_jax.synthetic")
    (folder / f"{stem}cpos.txt").write_text(format_rectangles(scene.positives))
    (folder / f"{stem}cneg.txt").write_text(format_rectangles(scene.negatives))


def _owned(child: pathlib.Path) -> bool:
    """Whether write_dataset makes this entry of a dataset folder (its other entries are the user's)."""
    if child.name == META_NAME:
        return True
    return child.is_dir() and (child.name == "processedData" or bool(cornell.FOLDER_PATTERN.fullmatch(child.name)))


def _check_out(out: pathlib.Path, overwrite: bool) -> None:
    """Refuse an `out` that write_dataset may not replace: a file, or a folder with anything in it
    unless `overwrite` and it is a synthetic set (complete, or what an older version left half-written)."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a directory")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise ValueError(f"--out {out} is not empty; pass --overwrite to replace a synthetic dataset there")
        if not ((out / META_NAME).is_file() or is_partial_dataset(out)):
            raise ValueError(f"refusing to overwrite {out}: it holds no {META_NAME} and files the generator "
                             "does not make, so it may not be a synthetic dataset")


def is_partial_dataset(root) -> bool:
    """A folder with no metadata that holds nothing but a synthetic set's files: what a run that
    was stopped while writing straight into it (before writes became atomic) leaves behind."""
    root = pathlib.Path(root)
    if not root.is_dir() or (root / META_NAME).exists():
        return False
    for child in root.iterdir():
        if not _owned(child):
            return False
        pattern = _PROCESSED_FILE if child.name == "processedData" else cornell.FILE_PATTERN
        for entry in child.iterdir():
            if not (pattern.fullmatch(entry.name) and entry.is_file()):
                return False
    return True


def write_dataset(out, photos: int, seed: int, overwrite: bool = False, progress: bool = False) -> dict:
    """Write `photos` synthetic photos in Cornell layout under `out`; returns a short summary."""
    if isinstance(photos, bool) or not isinstance(photos, (int, np.integer)) or not 1 <= photos <= MAX_PHOTOS:
        raise ValueError(f"photos must be an integer in [1, {MAX_PHOTOS}], got {photos!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    out = pathlib.Path(os.path.abspath(out))  # a name to stage and rename, also for "." or "x/.."
    _check_out(out, overwrite)
    # an `out` that is there now passed _check_out, so it may be replaced; one that appears later may not
    with publish.staged(out.parent, out.name, overwrite=out.exists(), keep=lambda entry: not _owned(entry)) as root:
        (root / out.name).mkdir()  # not mkdtemp: its 0700 mode would become the dataset's
        summary = _write_files(root / out.name, photos, seed, progress)
    return summary


@dataclasses.dataclass(frozen=True)
class WrittenPhoto:
    """What the dataset's index files say of a photo that _write_group wrote."""
    stem: str
    folder: str
    object_id: int
    category: str
    background: str
    rectangles: int
    meta: dict


def _planned_object(seed: int, planned: PlannedPhoto) -> ObjectSpec:
    return sample_object(np.random.default_rng([seed, 1, planned.object_index]), planned.category, planned.object_index)


def _planned_background(seed: int, planned: PlannedPhoto) -> Background:
    name = f"pcdb_{planned.background_index + 1:04d}"
    return make_background(np.random.default_rng([seed, 2, planned.background_index]), name)


def posed_photo(seed: int, index: int) -> tuple[Scene, Posed]:
    """Photo `index` (0-based) of the set written with `seed`, drawn again, and its posed object."""
    planned = plan(seed, index + 1)[index]
    return make_posed_scene(np.random.default_rng([seed, 3, planned.index]), _planned_object(seed, planned),
                            _planned_background(seed, planned))


def _write_group(out: pathlib.Path, seed: int, group: list[PlannedPhoto]) -> list[WrittenPhoto]:
    """Draw and write the photos of one background (consecutive in the plan), in order."""
    spec, background, written = None, None, []
    for planned in group:
        if spec is None or spec.object_id != planned.object_index:
            spec = _planned_object(seed, planned)
        if background is None:
            background = _planned_background(seed, planned)
        scene = make_scene(np.random.default_rng([seed, 3, planned.index]), spec, background)
        folder_name, stem = photo_stem(planned.index)
        folder = out / folder_name
        folder.mkdir(exist_ok=True)
        write_photo(folder, stem, scene)
        written.append(WrittenPhoto(stem, folder_name, spec.object_id, spec.category, background.name,
                                    len(scene.positives) + len(scene.negatives), scene.meta))
    return written


def _write_files(out: pathlib.Path, photos: int, seed: int, progress: bool) -> dict:
    """Every file of the dataset into the (empty) folder `out`, the metadata last. The photos of one
    background are drawn on one thread, the groups on WRITERS threads (the drawing's numpy and the PNG and
    TIFF encoders release the GIL); every file's bytes are what one thread would write."""
    (out / "processedData").mkdir()
    z_lines, mapping_lines, metas = [], [], {}
    start, done, every = time.monotonic(), 0, max(1, photos // 10)
    groups = [list(group) for _, group in itertools.groupby(plan(seed, photos), key=lambda p: p.background_index)]
    with concurrent.futures.ThreadPoolExecutor(WRITERS) as pool:
        for written in pool.map(lambda group: _write_group(out, seed, group), groups):
            for photo in written:
                z_lines += [f"{photo.stem[3:]} {photo.object_id} {photo.category} {photo.background}\n"] * photo.rectangles
                mapping_lines.append(f"{photo.stem}r.png {photo.background}r.png\n")
                metas[photo.stem] = {"folder": photo.folder, **photo.meta}
            if progress and (done // every != (done + len(written)) // every or done + len(written) == photos):
                print(f"synthetic: {done + len(written)}/{photos} photos ({time.monotonic() - start:.1f} s)",
                      file=sys.stderr, flush=True)
            done += len(written)
    (out / "processedData" / "z.txt").write_text("".join(z_lines))
    (out / "processedData" / "backgroundMapping.txt").write_text("".join(mapping_lines))
    header = {
        "generator": "kosmos_jax.sources.synthetic",
        "format_version": 1,
        "seed": seed,
        "count": photos,
        "depth": {
            "units": "metres",
            "convention": "distance from the camera (GG-CNN-processed Cornell d.tiff): objects are nearer, "
            "so smaller, than the table; table plane 1/depth = a + b*y + c*x at pixel centres, "
            "(a, b, c) = table_inverse_depth",
            "min_object_height_m": MIN_OBJECT_HEIGHT_M,
        },
        "categories": sorted(CATEGORIES),
    }
    lines = [f"{json.dumps(stem)}: {json.dumps(meta, separators=(',', ':'))}" for stem, meta in metas.items()]
    text = json.dumps(header, indent=1)[:-2] + ',\n "photos": {\n' + ",\n".join(lines) + "\n }\n}\n"
    (out / META_NAME).write_text(text)
    objects = sorted({m["object_id"] for m in metas.values()})
    return {"photos": photos, "objects": len(objects),
            "categories": sorted({m["category"] for m in metas.values()}),
            "seconds": round(time.monotonic() - start, 2)}


def read_meta(root) -> dict[str, dict]:
    """The per-photo metadata of a synthetic dataset under `root`: {"pcd0100": {...}, ...}."""
    return read_header(root)["photos"]


def read_header(root) -> dict:
    """The whole synthetic_meta.json of a synthetic dataset under `root`: its seed, count, ... and "photos"."""
    path = pathlib.Path(root) / META_NAME
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: {root} is not a synthetic dataset (or predates its metadata)")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from None
    if data.get("generator") != "kosmos_jax.sources.synthetic" or "photos" not in data:
        raise ValueError(f"{path}: not written by kosmos_jax.sources.synthetic")
    return data


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("string", "out", None, "dataset folder (created)")
    define("integer", "photos", None, f"number of photos, 1..{MAX_PHOTOS}", lower_bound=1, upper_bound=MAX_PHOTOS)
    define("integer", "seed", 0, "non-negative integer", lower_bound=0)
    define("bool", "overwrite", False, "replace a synthetic dataset already in --out")
    define("bool", "quiet", False, "no progress on stderr")
    flags.mark_flags_as_required(["out", "photos"], flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_flags, write_command, argv, prog="python -m kosmos_jax.sources.synthetic",
                                doc=__doc__)


def write_command(args) -> int:
    try:
        summary = write_dataset(pathlib.Path(args.out), args.photos, args.seed, overwrite=args.overwrite,
                                progress=not args.quiet and args.photos >= 20)
    except ValueError as error:
        raise commands.UsageError(str(error)) from None
    print(f"wrote {summary['photos']} photos of {summary['objects']} objects "
          f"({len(summary['categories'])} categories) to {args.out} in {summary['seconds']} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
