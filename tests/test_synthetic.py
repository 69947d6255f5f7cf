"""Synthetic Cornell-format scenes: layout, file formats, determinism, grasp validity, depth.

The grasp checks do not trust the generator: the object mask is rebuilt from the written depth
file and the table plane recorded in the metadata, the rectangles are parsed from the text files,
and part polygons are tested with shapely.
"""

import filecmp
import json
import math
import os
import pathlib
import re
import socket
import subprocess
import sys
from collections import Counter

import cv2
import numpy as np
import pytest
import tifffile
from shapely.geometry import Point, Polygon

from kosmos_jax import geometry
from kosmos_jax.sources import cornell
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.sources.synthetic.objects import CATEGORIES, PALETTE

PHOTOS = 60  # 5 photos per object at most, so >= 12 objects: the first round shows 12+ categories
SEED = 7
MASK_THRESHOLD_M = 0.004  # half the generator's minimum object height


@pytest.fixture(scope="session")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("synthetic") / "cornell"
    scenes.write_dataset(root, PHOTOS, SEED)
    meta = json.loads((root / "synthetic_meta.json").read_text())
    return root, meta


def parse_rectangles(path: pathlib.Path) -> np.ndarray:
    """[R, 4, 2] corners, parsed here rather than by the project's reader."""
    values = [float(v) for line in path.read_text().splitlines() for v in line.split()]
    assert len(values) % 8 == 0, path
    return np.array(values).reshape(-1, 4, 2)


def photo_paths(root, stem, meta):
    folder = root / meta["photos"][stem]["folder"]
    return {kind: folder / f"{stem}{kind}" for kind in ("r.png", "d.tiff", "cpos.txt", "cneg.txt")}


def object_mask_from_depth(depth, inverse_depth):
    a, b, c = inverse_depth
    rows, cols = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]]
    table = 1.0 / (a + b * (rows + 0.5) + c * (cols + 0.5))
    return table - depth > MASK_THRESHOLD_M


def on_mask(mask, points):
    points = np.atleast_2d(points)
    cols, rows = np.floor(points[:, 0]).astype(int), np.floor(points[:, 1]).astype(int)
    ok = (rows >= 0) & (rows < mask.shape[0]) & (cols >= 0) & (cols < mask.shape[1])
    hit = np.zeros(len(points), bool)
    hit[ok] = mask[rows[ok], cols[ok]]
    return hit


def run_length(mask, centre, direction):
    """Length of the run of mask pixels through `centre` along +-direction (0.1 px steps)."""
    total = 0.0
    for sign in (-1, 1):
        s = 0.0
        while on_mask(mask, centre + sign * (s + 0.1) * direction)[0]:
            s += 0.1
        total += s
    return total


def antipodal_verdict(mask, corners):
    """(ok, reason): centre on the object, both jaws entirely off it, opening a bit wider than it."""
    centre = corners.mean(axis=0)
    if not on_mask(mask, centre)[0]:
        return False, "centre off the object"
    for a, b in ((corners[0], corners[3]), (corners[1], corners[2])):
        jaw = a + np.linspace(0, 1, 60)[:, None] * (b - a)
        if on_mask(mask, jaw).any():
            return False, "a jaw lands on the object"
    opening = corners[1] - corners[0]
    width = float(np.hypot(*opening))
    crossing = run_length(mask, centre, opening / width)
    if not 0 < width - crossing <= 30:
        return False, f"opening {width:.1f} vs object {crossing:.1f} along the opening axis"
    return True, ""


def part_polygon(part):
    return Polygon(part["polygon"], holes=part["holes"])


# ---- plan and naming -------------------------------------------------------------------------


def test_photo_stems_continue_into_new_folders_every_100_photos():
    assert scenes.photo_stem(0) == ("01", "pcd0100")
    assert scenes.photo_stem(99) == ("01", "pcd0199")
    assert scenes.photo_stem(100) == ("02", "pcd0200")
    assert scenes.photo_stem(900) == ("10", "pcd1000")


def test_plan_shows_each_object_in_several_photos_and_many_categories():
    long_plan = scenes.plan(0, 2000)
    per_object = Counter(p.object_index for p in long_plan)
    mean = np.mean(list(per_object.values()))
    assert 3.3 < mean < 4.1, mean  # Cornell: 885 photos of 280 objects, about 3.7 a object
    assert len(set(per_object.values())) > 1
    assert [p.index for p in long_plan] == list(range(2000))
    for index in per_object:
        rows = [p for p in long_plan if p.object_index == index]
        assert len({(p.category, p.background_index) for p in rows}) == 1
    assert len({p.category for p in scenes.plan(0, PHOTOS)}) >= 12
    assert scenes.plan(0, 50) == long_plan[:50]
    assert scenes.plan(1, 50) != long_plan[:50]


# ---- layout and formats ----------------------------------------------------------------------


def test_layout_images_and_depth(dataset):
    root, meta = dataset
    assert sorted(p.name for p in root.iterdir()) == ["01", "processedData", "synthetic_meta.json"]
    stems = [scenes.photo_stem(i)[1] for i in range(PHOTOS)]
    assert list(meta["photos"]) == stems
    assert sorted(p.name for p in (root / "01").iterdir()) == sorted(
        f"{s}{k}" for s in stems for k in ("r.png", "d.tiff", "cpos.txt", "cneg.txt"))
    bgr = cv2.imread(str(root / "01" / "pcd0100r.png"), cv2.IMREAD_UNCHANGED)
    assert bgr.shape == (480, 640, 3) and bgr.dtype == np.uint8
    depth = tifffile.imread(root / "01" / "pcd0100d.tiff")
    assert depth.shape == (480, 640) and depth.dtype == np.float32
    assert np.isfinite(depth).all()


def test_rectangle_files_are_in_cornell_text_style(dataset):
    root, meta = dataset
    for stem in list(meta["photos"])[:10]:
        for kind in ("cpos.txt", "cneg.txt"):
            text = photo_paths(root, stem, meta)[kind].read_text()
            lines = text.split("\n")
            assert lines[-1] == ""  # every line ends with a newline, as in the real 01/ files
            for number, line in enumerate(lines[:-1]):
                # "253 319.7 " on the first three lines of a rectangle, "251 345.7" on the fourth
                pattern = r"\d+(\.\d{1,3})? \d+(\.\d{1,3})?" + (" " if number % 4 < 3 else "")
                assert re.fullmatch(pattern, line), (stem, kind, number, line)
    counts = [len(parse_rectangles(photo_paths(root, s, meta)["cpos.txt"])) for s in meta["photos"]]
    assert min(counts) >= 1 and max(counts) <= 7 and np.mean(counts) > 3


def test_z_txt_maps_photos_to_objects_like_cornell(dataset):
    root, meta = dataset
    lines = (root / "processedData" / "z.txt").read_text().splitlines()
    by_photo = Counter()
    for line in lines:
        match = re.fullmatch(r"(\d{4}) (\d+) ([A-Za-z_]+) (pcdb_\d{4})", line)
        assert match, line
        image, object_id, category, background = match.groups()
        photo = meta["photos"][f"pcd{image}"]
        assert (int(object_id), category, background) == (photo["object_id"], photo["category"], photo["background"])
        by_photo[image] += 1
    for stem in meta["photos"]:  # one line a rectangle, as in Cornell's z.txt
        paths = photo_paths(root, stem, meta)
        assert by_photo[stem[3:]] == len(parse_rectangles(paths["cpos.txt"])) + len(parse_rectangles(paths["cneg.txt"]))
    photos_per_object = Counter(m["object_id"] for m in meta["photos"].values())
    assert max(photos_per_object.values()) > 1 and len(photos_per_object) >= 12
    mapping = (root / "processedData" / "backgroundMapping.txt").read_text().splitlines()
    assert mapping[0] == f"pcd0100r.png {meta['photos']['pcd0100']['background']}r.png"


def test_metadata_describes_every_photo(dataset):
    root, meta = dataset
    assert meta["seed"] == SEED and meta["count"] == PHOTOS
    categories = {m["category"] for m in meta["photos"].values()}
    assert len(categories) >= 12 and categories <= set(CATEGORIES)
    for stem, m in meta["photos"].items():
        for key in ("name", "colour_phrase", "shape_phrase", "purpose", "strategy", "position"):
            assert isinstance(m[key], str) and m[key], (stem, key)
        assert m["colour"] and set(m["colour"]) <= set(PALETTE)
        assert m["shape"] and all(isinstance(w, str) for w in m["shape"])
        assert m["strategy"].endswith(".") and len(m["strategy"].split()) > 10
        positives = parse_rectangles(photo_paths(root, stem, meta)["cpos.txt"])
        assert len(m["grasp_parts"]) == len(positives)
        names = {p["name"] for p in m["parts"] if p["graspable"]}
        assert set(m["grasp_parts"]) <= names
    # Parts are named (handle, head, ...), not just "body", across the set.
    assert {"handle", "head", "body", "blades", "rim"} <= {p for m in meta["photos"].values() for p in m["grasp_parts"]}


# ---- grasp validity --------------------------------------------------------------------------


def test_positive_grasps_close_across_their_part(dataset):
    root, meta = dataset
    checked = 0
    for stem, m in meta["photos"].items():
        paths = photo_paths(root, stem, meta)
        mask = object_mask_from_depth(tifffile.imread(paths["d.tiff"]), m["table_inverse_depth"])
        parts = {p["name"]: part_polygon(p) for p in m["parts"]}
        for corners, part in zip(parse_rectangles(paths["cpos.txt"]), m["grasp_parts"]):
            ok, reason = antipodal_verdict(mask, corners)
            assert ok, (stem, part, reason)
            centre = Point(*corners.mean(axis=0))
            assert parts[part].buffer(0.5).contains(centre), (stem, part)
            x, y, w, h, theta = geometry.corners_to_grasps(corners)
            assert 8 <= h <= 25.01 and w <= 100.01, (stem, w, h)
            checked += 1
    assert checked > 3 * PHOTOS


def test_negative_grasps_fail_the_same_check(dataset):
    root, meta = dataset
    kinds = Counter()
    for stem, m in meta["photos"].items():
        paths = photo_paths(root, stem, meta)
        mask = object_mask_from_depth(tifffile.imread(paths["d.tiff"]), m["table_inverse_depth"])
        negatives = parse_rectangles(paths["cneg.txt"])
        assert len(negatives) == len(m["negative_kinds"])
        for corners, kind in zip(negatives, m["negative_kinds"]):
            ok, reason = antipodal_verdict(mask, corners)
            assert not ok, (stem, kind)
            kinds[kind] += 1
    assert set(kinds) == {"along", "narrow", "off"}


def test_the_check_depends_on_the_corner_order(dataset):
    """With p1 -> p2 read as the opening (the wrong order), the positives stop being grasps."""
    root, meta = dataset
    verdicts = []
    for stem, m in list(meta["photos"].items())[:20]:
        paths = photo_paths(root, stem, meta)
        mask = object_mask_from_depth(tifffile.imread(paths["d.tiff"]), m["table_inverse_depth"])
        for corners in parse_rectangles(paths["cpos.txt"]):
            verdicts.append(antipodal_verdict(mask, np.roll(corners, -1, axis=0))[0])
    assert np.mean(verdicts) < 0.2


def test_reader_reads_synthetic_output_back(dataset):
    root, meta = dataset
    photos = cornell.load_photos(root)
    assert [p.id for p in photos] == list(meta["photos"])
    for photo in photos[:: max(1, PHOTOS // 12)]:
        paths = photo_paths(root, photo.id, meta)
        expected = geometry.corners_to_grasps(parse_rectangles(paths["cpos.txt"]))
        np.testing.assert_allclose(photo.grasps, expected)
        assert photo.negatives.shape == (len(parse_rectangles(paths["cneg.txt"])), 5)
        written = meta["photos"][photo.id]
        assert (photo.object_id, photo.category) == (written["object_id"], written["category"])
        assert photo.rgb.shape == (480, 640, 3)
        np.testing.assert_array_equal(photo.depth, tifffile.imread(paths["d.tiff"]))
        assert photo.nan_dropped == 0


# ---- depth -----------------------------------------------------------------------------------


def test_depth_is_distance_objects_nearer_than_the_table(dataset):
    root, meta = dataset
    for stem, m in list(meta["photos"].items())[:: max(1, PHOTOS // 10)]:
        depth = tifffile.imread(photo_paths(root, stem, meta)["d.tiff"])
        mask = object_mask_from_depth(depth, m["table_inverse_depth"])
        assert 200 < mask.sum() < 20000, stem
        # The object's own polygons agree with the mask taken from depth.
        drawn = np.zeros(depth.shape, np.uint8)
        for part in m["parts"]:
            part_mask = np.zeros(depth.shape, np.uint8)
            for ring, value in [(part["polygon"], 1)] + [(hole, 0) for hole in part["holes"]]:
                cv2.fillPoly(part_mask, [np.round((np.array(ring) - 0.5) * 16).astype(np.int32)], value, shift=4)
            drawn |= part_mask
        iou = (drawn.astype(bool) & mask).sum() / (drawn.astype(bool) | mask).sum()
        assert iou > 0.97, (stem, iou)
        # Nearer the camera on the object; smooth table: neighbour steps small off the object's edges.
        a, b, c = m["table_inverse_depth"]
        rows, cols = np.nonzero(mask)
        table = 1 / (a + b * (rows + 0.5) + c * (cols + 0.5))
        assert np.all(depth[rows, cols] < table - 0.007) and np.all(depth[rows, cols] > table - 0.25)
        edges = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        step = np.abs(np.diff(depth, axis=0))[~(edges[1:] | edges[:-1])]
        assert np.percentile(step, 99) < 0.01
        assert 0.7 < depth[-1].mean() < 0.95 and depth.max() < 2.1  # bottom row near, floor ~2 m


def test_depth_range_matches_the_real_processed_files(dataset, cornell_root):
    root, meta = dataset
    real = tifffile.imread(cornell_root / "01" / "pcd0100d.tiff")
    ours = tifffile.imread(root / "01" / "pcd0100d.tiff")
    assert ours.dtype == real.dtype and ours.shape == real.shape
    lo, hi = np.percentile(real, [1, 99])
    our_lo, our_hi = np.percentile(ours, [1, 99])
    assert lo - 0.1 < our_lo < lo + 0.15 and hi - 0.4 < our_hi < hi + 0.1
    # Same convention: the bottom of the photo (near table) is nearer than the top.
    assert real[-20:].mean() < real[:20].mean() and ours[-20:].mean() < ours[:20].mean()


# ---- determinism -----------------------------------------------------------------------------


def all_files(root):
    return sorted(p.relative_to(root) for p in root.rglob("*") if p.is_file())


def test_same_seed_same_bytes_and_prefix_stable(dataset, tmp_path):
    root, _ = dataset
    first, second, other = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    scenes.write_dataset(first, 5, SEED)
    scenes.write_dataset(second, 5, SEED)
    scenes.write_dataset(other, 5, SEED + 1)
    assert all_files(first) == all_files(second) == all_files(other)
    for rel in all_files(first):
        assert filecmp.cmp(first / rel, second / rel, shallow=False), rel
    for rel in all_files(first / "01"):  # photo k does not depend on how many photos follow it
        assert filecmp.cmp(first / "01" / rel, root / "01" / rel, shallow=False), rel
    for rel in [pathlib.Path("01/pcd0100r.png"), pathlib.Path("01/pcd0100d.tiff"), pathlib.Path("01/pcd0100cpos.txt")]:
        assert not filecmp.cmp(first / rel, other / rel, shallow=False), rel


def test_the_writer_threads_change_no_byte(tmp_path, monkeypatch):
    """Enough photos for several backgrounds, so the two threads each draw some; the index files keep the plan's order."""
    threaded = tmp_path / "threads"
    scenes.write_dataset(threaded, 40, SEED)
    monkeypatch.setattr(scenes, "WRITERS", 1)
    alone = tmp_path / "one"
    scenes.write_dataset(alone, 40, SEED)
    assert len({p.background_index for p in scenes.plan(SEED, 40)}) > 2
    assert all_files(threaded) == all_files(alone)
    for rel in all_files(alone):
        assert filecmp.cmp(threaded / rel, alone / rel, shallow=False), rel


# ---- command line ----------------------------------------------------------------------------


@pytest.mark.parametrize("args, message", [
    (["--photos", "0"], "flag --photos=0: 0 is not an integer in the range [1, "),
    (["--photos", "-3"], "flag --photos=-3: -3 is not an integer in the range [1, "),
    (["--photos", "2", "--seed", "-1"], "flag --seed=-1: -1 is not a non-negative integer"),
    (["--photos", "many"], "flag --photos=many: invalid literal for int()"),
])
def test_cli_rejects_bad_numbers(tmp_path, capsys, args, message):
    assert scenes.main(["--out", str(tmp_path / "out"), *args]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_cli_refuses_to_clobber_and_overwrites_only_its_own_output(tmp_path, capsys):
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    assert scenes.main(["--out", str(foreign), "--photos", "1"]) == 2
    assert "is not empty; pass --overwrite" in capsys.readouterr().err
    assert scenes.main(["--out", str(foreign), "--photos", "1", "--overwrite"]) == 2
    assert "holds no synthetic_meta.json" in capsys.readouterr().err
    assert (foreign / "notes.txt").read_text() == "keep me"

    a_file = tmp_path / "file"
    a_file.write_text("x")
    assert scenes.main(["--out", str(a_file), "--photos", "1"]) == 2
    assert "is not a directory" in capsys.readouterr().err

    out = tmp_path / "out"
    assert scenes.main(["--out", str(out), "--photos", "3", "--seed", "2"]) == 0
    assert "wrote 3 photos" in capsys.readouterr().err
    (out / "extra.txt").write_text("user file")
    assert scenes.main(["--out", str(out), "--photos", "1", "--overwrite"]) == 0
    expected = [f"pcd0100{k}" for k in ("cneg.txt", "cpos.txt", "d.tiff", "r.png")]
    assert sorted(p.name for p in (out / "01").iterdir()) == expected
    assert json.loads((out / "synthetic_meta.json").read_text())["count"] == 1
    assert (out / "extra.txt").exists()


def test_write_dataset_reports_progress_on_stderr(tmp_path, capsys):
    summary = scenes.write_dataset(tmp_path / "p", 2, 0, progress=True)
    assert "synthetic: 2/2 photos" in capsys.readouterr().err
    assert summary["photos"] == 2 and summary["objects"] >= 1


def test_write_dataset_rejects_bad_arguments(tmp_path):
    for photos in (0, -1, 2.5, True, scenes.MAX_PHOTOS + 1):
        with pytest.raises(ValueError, match="photos must be an integer"):
            scenes.write_dataset(tmp_path / "x", photos, 0)
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        scenes.write_dataset(tmp_path / "x", 1, -5)


def test_make_scene_is_a_pure_function_of_its_generator():
    from kosmos_jax.sources.synthetic.objects import sample_object
    from kosmos_jax.sources.synthetic.render import make_background

    spec = sample_object(np.random.default_rng(0), "Mug", 0)
    background = make_background(np.random.default_rng(1), "pcdb_0001")
    one = scenes.make_scene(np.random.default_rng(2), spec, background)
    two = scenes.make_scene(np.random.default_rng(2), spec, background)
    three = scenes.make_scene(np.random.default_rng(3), spec, background)
    np.testing.assert_array_equal(one.rgb, two.rgb)
    np.testing.assert_array_equal(one.depth, two.depth)
    np.testing.assert_array_equal(one.positives, two.positives)
    assert one.meta == two.meta and one.meta["pose"] != three.meta["pose"]
    assert one.rgb.shape == (480, 640, 3) and one.depth.shape == (480, 640)
    assert one.positives.shape[1:] == (4, 2) and len(one.positives) == len(one.meta["grasp_parts"])
    assert one.negatives.shape[1:] == (4, 2) and len(one.negatives) == len(one.meta["negative_kinds"])
    with pytest.raises(ValueError, match="unknown synthetic category 'Teapot'"):
        sample_object(np.random.default_rng(0), "Teapot", 0)


def test_read_meta_returns_the_photos_and_names_a_bad_file(dataset, tmp_path):
    root, meta = dataset
    assert scenes.read_meta(root) == meta["photos"]
    with pytest.raises(FileNotFoundError, match="synthetic_meta.json not found"):
        scenes.read_meta(tmp_path)
    (tmp_path / "synthetic_meta.json").write_text("{broken")
    with pytest.raises(ValueError, match="synthetic_meta.json: not valid JSON"):
        scenes.read_meta(tmp_path)


# ---- atomic writing --------------------------------------------------------------------------


def snapshot(root):
    return {rel: (root / rel).read_bytes() for rel in all_files(root)}


def stop_at_second_scene(monkeypatch, error):
    real, calls = scenes.make_scene, []

    def make_scene(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise error
        return real(*args, **kwargs)

    monkeypatch.setattr(scenes, "make_scene", make_scene)


def test_an_interrupted_first_write_leaves_nothing(tmp_path, monkeypatch):
    stop_at_second_scene(monkeypatch, KeyboardInterrupt())
    with pytest.raises(KeyboardInterrupt):
        scenes.write_dataset(tmp_path / "out", 3, 0)
    assert list(tmp_path.iterdir()) == []  # neither the folder nor a hidden partial sibling
    monkeypatch.undo()
    scenes.write_dataset(tmp_path / "out", 3, 0)  # and the next run simply writes it
    assert scenes.read_meta(tmp_path / "out").keys() == {"pcd0100", "pcd0101", "pcd0102"}


def test_an_interrupted_overwrite_keeps_the_old_set_whole(tmp_path, monkeypatch):
    out = tmp_path / "out"
    scenes.write_dataset(out, 2, 1)
    (out / "notes.txt").write_text("mine")
    before = snapshot(out)
    stop_at_second_scene(monkeypatch, RuntimeError("disk full"))
    with pytest.raises(RuntimeError, match="disk full"):
        scenes.write_dataset(out, 3, 0, overwrite=True)
    assert snapshot(out) == before and [p.name for p in tmp_path.iterdir()] == ["out"]
    monkeypatch.undo()
    scenes.write_dataset(out, 3, 0, overwrite=True)
    assert json.loads((out / "synthetic_meta.json").read_text())["count"] == 3
    assert (out / "notes.txt").read_text() == "mine" and [p.name for p in tmp_path.iterdir()] == ["out"]


def test_a_killed_writers_partial_folder_is_removed_by_the_next_write(tmp_path):
    finished = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead_pid = int(finished.stdout)
    prefix = f".staging-out-{socket.gethostname()}-"
    dead, live = tmp_path / f"{prefix}{dead_pid}-0a1b2c3d", tmp_path / f"{prefix}{os.getpid()}-4e5f6a7b"
    for folder in (dead, live):
        (folder / "01").mkdir(parents=True)
        (folder / "01" / "pcd0100r.png").write_bytes(b"half")
    scenes.write_dataset(tmp_path / "out", 1, 0)
    assert not dead.exists()
    assert live.exists()  # a writer still running (here: this process) is left alone
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, "out"])


def test_the_written_folder_gets_the_usual_permissions(tmp_path):
    umask = os.umask(0o022)
    os.umask(umask)
    scenes.write_dataset(tmp_path / "out", 1, 0)
    assert (tmp_path / "out").stat().st_mode & 0o777 == 0o777 & ~umask


def test_partial_dataset_is_recognised_only_when_it_holds_nothing_else(tmp_path):
    root = tmp_path / "old"
    scenes.write_dataset(root, 2, 0)
    assert not scenes.is_partial_dataset(root)  # complete
    (root / "synthetic_meta.json").unlink()  # what an older version stopped mid-write left
    assert scenes.is_partial_dataset(root)
    (root / "processedData" / "z.txt").unlink()
    assert scenes.is_partial_dataset(root)
    (root / "01" / "holiday.jpg").write_bytes(b"")
    assert not scenes.is_partial_dataset(root)
    (root / "01" / "holiday.jpg").unlink()
    (root / "README").write_text("")
    assert not scenes.is_partial_dataset(root)
    assert not scenes.is_partial_dataset(tmp_path / "absent")


def test_overwrite_replaces_what_an_older_version_left_half_written(tmp_path, capsys):
    out = tmp_path / "out"
    scenes.write_dataset(out, 2, 0)
    (out / "synthetic_meta.json").unlink()  # stopped while writing straight into out
    (out / "01" / "pcd0101r.png").unlink()
    with pytest.raises(ValueError, match="is not empty; pass --overwrite"):
        scenes.write_dataset(out, 2, 0)
    assert scenes.main(["--out", str(out), "--photos", "2", "--overwrite"]) == 0
    assert scenes.read_meta(out).keys() == {"pcd0100", "pcd0101"} and (out / "01" / "pcd0101r.png").is_file()
    (out / "synthetic_meta.json").unlink()
    (out / "01" / "holiday.jpg").write_bytes(b"photo")  # not the generator's: maybe not a synthetic set
    with pytest.raises(ValueError, match="refusing to overwrite .* holds no synthetic_meta.json and files"):
        scenes.write_dataset(out, 2, 0, overwrite=True)
    assert (out / "01" / "holiday.jpg").read_bytes() == b"photo"


def test_colour_words_name_every_large_painted_area():
    """A palette colour covering a fifth of an object's top view (a part, or a decal painted over
    it) is among its colour words, so a colour instruction can refer to what the photo shows."""
    from kosmos_jax.sources.synthetic.objects import CATEGORIES, PALETTE, sample_object

    names_of = {rgb: name for name, rgb in PALETTE.items()}
    for category in CATEGORIES:
        for seed in range(12):
            spec = sample_object(np.random.default_rng(seed), category, 0)
            outline = Polygon(spec.parts[0].shell).buffer(0)
            for part in spec.parts[1:]:
                outline = outline.union(Polygon(part.shell).buffer(0))
            visible = {}
            for part in spec.parts:
                area = Polygon(part.shell).buffer(0).area
                visible[part.colour] = visible.get(part.colour, 0.0) + area
            for decal in spec.decals:  # paint replaces the colour under it
                area = Polygon(decal.shell).buffer(0).intersection(outline).area
                visible[decal.colour] = visible.get(decal.colour, 0.0) + area
                under = [p.colour for p in spec.parts if Polygon(p.shell).buffer(0).intersects(Polygon(decal.shell))]
                if under:
                    visible[under[0]] -= area
            for colour, area in visible.items():
                if colour in names_of and area >= 0.2 * outline.area:
                    assert names_of[colour] in spec.colours, (category, seed, names_of[colour], spec.colours)
