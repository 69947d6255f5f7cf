"""Cornell reader: real files against independent counts, quirks, the CLI, broken copies."""

import json
import math
import pathlib
import re
import shutil
import subprocess
import sys
import types

import numpy as np
import pytest

from kosmos_jax.sources import cornell

REPO = pathlib.Path(__file__).resolve().parents[1]


def independent_counts(path: pathlib.Path) -> tuple[int, int]:
    """(rectangles kept, rectangles with NaN) by counting raw lines, not via the reader."""
    if not path.exists():
        return 0, 0
    lines = [line for line in re.split(rb"\r\n|\r|\n", path.read_bytes()) if line.strip()]
    assert len(lines) % 4 == 0
    groups = [lines[i:i + 4] for i in range(0, len(lines), 4)]
    nan = sum(any(b"nan" in line.lower() for line in group) for group in groups)
    return len(groups) - nan, nan


def all_cpos(root: pathlib.Path) -> list[pathlib.Path]:
    return sorted(root.glob("*/pcd*cpos.txt"), key=lambda p: p.name)


def test_every_real_file_counted_like_an_independent_count(cornell_root):
    photos = cornell.load_photos(cornell_root, load_images=False)
    assert [p.id for p in photos] == [f.name[:7] for f in all_cpos(cornell_root)]
    assert len(photos) == 101
    for photo in photos:
        folder = next(cornell_root.glob(f"*/{photo.id}cpos.txt")).parent
        kept, nan = independent_counts(folder / f"{photo.id}cpos.txt")
        assert (len(photo.grasps), photo.nan_dropped) == (kept, nan), photo.id
        neg_kept, _ = independent_counts(folder / f"{photo.id}cneg.txt")
        assert len(photo.negatives) == neg_kept, photo.id
        assert photo.rgb is None and photo.depth is None
        assert np.isfinite(photo.grasps).all()


def test_known_quirks(cornell_root):
    photos = {p.id: p for p in cornell.iter_photos(cornell_root, load_images=False)}
    assert photos["pcd0132"].nan_dropped == 2
    assert photos["pcd0165"].nan_dropped == 1
    assert sum(p.nan_dropped for p in photos.values()) == 3
    assert (cornell_root / "01" / "pcd0154cneg.txt").stat().st_size == 0
    assert photos["pcd0154"].negatives.shape == (0, 5)
    # cornell/03 uses CRLF: first rectangle worked out by hand from the file's first four lines.
    assert b"\r\n" in (cornell_root / "03" / "pcd0312cpos.txt").read_bytes()
    p = [(326, 244.483), (341, 257), (352, 244), (337, 231.483)]
    expected = [sum(x for x, _ in p) / 4, sum(y for _, y in p) / 4,
                math.hypot(341 - 326, 257 - 244.483), math.hypot(352 - 341, 244 - 257),
                math.atan2(-(257 - 244.483), 341 - 326)]
    np.testing.assert_allclose(photos["pcd0312"].grasps[0], expected, rtol=1e-12)


def test_images_depth_and_object_map(cornell_root):
    photos = cornell.load_photos(cornell_root, ids=["pcd0100", "pcd0312"])
    first, crlf = photos
    assert first.rgb.shape == (480, 640, 3) and first.rgb.dtype == np.uint8
    assert first.depth.shape == (480, 640) and first.depth.dtype == np.float32
    assert crlf.depth is None  # cornell/03 ships no d.tiff
    z_lines = (cornell_root / "processedData" / "z.txt").read_text().splitlines()
    line = next(l for l in z_lines if l.startswith("0100 "))
    assert (first.object_id, first.category) == (int(line.split()[1]), line.split()[2])


def test_rgb_channel_order_is_rgb(tmp_path):
    import cv2
    bgr = np.zeros((4, 5, 3), np.uint8)
    bgr[..., 0] = 255  # blue in OpenCV's order
    cv2.imwrite(str(tmp_path / "pcd0001r.png"), bgr)
    (tmp_path / "pcd0001cpos.txt").write_text("")
    photo = cornell.load_photos(tmp_path)[0]
    assert photo.rgb[0, 0].tolist() == [0, 0, 255]


def test_lazy_and_listing_without_decoding(tmp_path, cornell_root):
    for photo_id in ("pcd0100", "pcd0101"):
        for suffix in ("r.png", "cpos.txt"):
            shutil.copy(cornell_root / "01" / f"{photo_id}{suffix}", tmp_path)
    (tmp_path / "pcd0101r.png").write_bytes(b"not a png at all")
    assert cornell.list_photo_ids(tmp_path) == ["pcd0100", "pcd0101"]
    photos = cornell.iter_photos(tmp_path)
    assert isinstance(photos, types.GeneratorType)
    assert next(photos).id == "pcd0100"  # the corrupt second image is not touched yet
    with pytest.raises(cornell.CornellFormatError, match="pcd0101r.png"):
        next(photos)


def test_flat_and_numbered_layouts_agree(tmp_path, cornell_root):
    flat, numbered = tmp_path / "flat", tmp_path / "numbered" / "07"
    flat.mkdir()
    numbered.mkdir(parents=True)
    for name in ("pcd0132cpos.txt", "pcd0132cneg.txt", "pcd0154cpos.txt", "pcd0154cneg.txt"):
        shutil.copy(cornell_root / "01" / name, flat)
        shutil.copy(cornell_root / "01" / name, numbered)
    a = cornell.load_photos(flat, load_images=False)
    b = cornell.load_photos(numbered.parent, load_images=False)
    assert [p.id for p in a] == [p.id for p in b] == ["pcd0132", "pcd0154"]
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x.grasps, y.grasps)


def test_line_endings_spaces_and_empty(tmp_path):
    rect = ["10 20", "30 20", "30 25", "10 25"]
    variants = {
        "lf": "\n".join(rect) + "\n",
        "crlf_no_final": "\r\n".join(rect),
        "mixed_trailing": "10 20 \r\n30 20\n30 25 \r10 25 ",
        "blank_lines": "\n10 20\n\n30 20\n30 25\n10 25\n\n\n",
    }
    for name, text in variants.items():
        path = tmp_path / f"{name}.txt"
        path.write_bytes(text.encode())
        grasps, dropped = cornell.read_rectangles(path)
        np.testing.assert_allclose(grasps, [[20, 22.5, 20, 5, 0]], err_msg=name)
        assert dropped == 0
    empty = tmp_path / "empty.txt"
    empty.write_bytes(b"")
    grasps, dropped = cornell.read_rectangles(empty)
    assert grasps.shape == (0, 5) and dropped == 0


def test_nan_rectangle_dropped_whole(tmp_path):
    path = tmp_path / "pcd0001cpos.txt"
    path.write_text("NaN NaN\n30 20\n30 25\n10 25\n10 20\n30 20\n30 25\n10 25\n")
    grasps, dropped = cornell.read_rectangles(path)
    assert dropped == 1 and grasps.shape == (1, 5)


@pytest.mark.parametrize("text, line", [
    ("1 2\n3 4\n5 6\n7 8\n9 10\n", 5),          # five lines: incomplete rectangle at line 5
    ("1 2\n3 4\n5 abc\n7 8\n", 3),               # not a number
    ("1 2\n3 4 5\n5 6\n7 8\n", 2),               # three numbers
    ("1 2\n3 4\n5 6\n7 inf\n", 4),               # infinite
    ("\n1 2\n\n3 4\n5 6\n", 2),                  # odd count: rectangle starting at line 2
])
def test_malformed_text_names_file_and_line(tmp_path, text, line):
    path = tmp_path / "pcd0001cpos.txt"
    path.write_text(text)
    with pytest.raises(cornell.CornellFormatError) as error:
        cornell.read_rectangles(path)
    message = str(error.value)
    assert str(path) in message and f"line {line}" in message
    assert isinstance(error.value, ValueError)


@pytest.mark.parametrize("text, line", [
    ("1 2\n3 4\n5 6\u2028\n7 x\n", 3),        # U+2028 is no line break: the error stays on line 3
    ("1 2\n\x0c3 4\n5 6\n7 8\n", 2),          # nor a form feed
    ("1 2\n3 4\x0b5 6\n7 8\n", 2),             # nor a vertical tab
    ("1 2\n3 4\n5 1_0\n7 8\n", 3),             # float() reads '1_0' as 10; a number has no underscore
    ("1 2\n3 \u0664\n5 6\n7 8\n", 2),         # float() reads Arabic-Indic digits too
])
def test_only_ascii_numbers_and_real_line_breaks(tmp_path, text, line):
    path = tmp_path / "pcd0001cpos.txt"
    path.write_bytes(text.encode())
    with pytest.raises(cornell.CornellFormatError, match=rf"pcd0001cpos\.txt, line {line}:"):
        cornell.read_rectangles(path)


def test_byte_order_mark_tabs_and_non_utf8(tmp_path):
    path = tmp_path / "pcd0001cpos.txt"
    path.write_bytes(b"\xef\xbb\xbf10 20\r\n30\t20\r\n30 25\r\n10 25\r\n")
    grasps, _ = cornell.read_rectangles(path)
    np.testing.assert_allclose(grasps, [[20, 22.5, 20, 5, 0]])
    path.write_bytes(b"10 20\n30 20\r30 \xff25\n10 25\n")
    with pytest.raises(cornell.CornellFormatError, match=r"pcd0001cpos\.txt, line 3, column 4: not UTF-8"):
        cornell.read_rectangles(path)


def raw_lines(data: bytes) -> list[bytes]:
    """Lines as the Cornell files break them, counted here without the reader."""
    return re.split(rb"\r\n|\r|\n", data)


@pytest.mark.parametrize("folder, name, deleted", [("01", "pcd0100cpos.txt", 6), ("01", "pcd0132cpos.txt", 1),
                                                  ("03", "pcd0312cpos.txt", 10)])
def test_real_file_with_a_line_deleted(tmp_path, cornell_root, folder, name, deleted):
    lines = raw_lines((cornell_root / folder / name).read_bytes())
    ending = b"\r\n" if folder == "03" else b"\n"
    broken = tmp_path / name
    broken.write_bytes(ending.join(lines[: deleted - 1] + lines[deleted:]))
    kept = [number for number, line in enumerate(raw_lines(broken.read_bytes()), start=1) if line.strip()]
    assert len(kept) % 4 == 3
    incomplete = kept[len(kept) - 3]  # the last rectangle has three of its four lines
    with pytest.raises(cornell.CornellFormatError) as error:
        cornell.read_rectangles(broken)
    assert f"{broken}, line {incomplete}:" in str(error.value)


@pytest.mark.parametrize("folder, name, line, bad", [
    ("01", "pcd0100cpos.txt", 7, "abc"), ("01", "pcd0165cpos.txt", 2, "1_0"),
    ("01", "pcd0100cneg.txt", 4, "3.2.1"), ("03", "pcd0312cpos.txt", 13, "x"),
])
def test_real_file_with_a_non_number_injected(tmp_path, cornell_root, folder, name, line, bad):
    data = (cornell_root / folder / name).read_bytes()
    lines = raw_lines(data)
    x = lines[line - 1].split()[0]
    lines[line - 1] = x + b" " + bad.encode()
    broken = tmp_path / name
    broken.write_bytes((b"\r\n" if b"\r\n" in data else b"\n").join(lines))
    cornell.read_rectangles(cornell_root / folder / name)  # the real file itself reads
    with pytest.raises(cornell.CornellFormatError) as error:
        cornell.read_rectangles(broken)
    assert f"{broken}, line {line}: not a number" in str(error.value)


def test_real_photo_with_a_truncated_image(tmp_path, cornell_root):
    for suffix in ("cpos.txt", "cneg.txt", "d.tiff"):
        shutil.copy(cornell_root / "01" / f"pcd0101{suffix}", tmp_path)
    png = (cornell_root / "01" / "pcd0101r.png").read_bytes()
    for length in (len(png) // 2, len(png) - 16):  # the end chunk alone missing is an error too
        (tmp_path / "pcd0101r.png").write_bytes(png[:length])
        with pytest.raises(cornell.CornellFormatError, match=r"pcd0101r\.png: cannot decode"):
            cornell.load_photos(tmp_path)
    (tmp_path / "pcd0101r.png").write_bytes(png)
    assert cornell.load_photos(tmp_path)[0].rgb.shape == (480, 640, 3)


def test_corrupt_and_truncated_png_are_errors(tmp_path, cornell_root):
    shutil.copy(cornell_root / "01" / "pcd0100cpos.txt", tmp_path)
    png = (cornell_root / "01" / "pcd0100r.png").read_bytes()
    for broken in (b"garbage bytes", b"", png[:200]):
        (tmp_path / "pcd0100r.png").write_bytes(broken)
        with pytest.raises(cornell.CornellFormatError, match="pcd0100r.png"):
            cornell.load_photos(tmp_path)


def test_round_trip_of_a_written_file(tmp_path):
    rng = np.random.default_rng(0)
    grasps = np.stack([rng.uniform(0, 640, 20), rng.uniform(0, 480, 20), rng.uniform(5, 80, 20),
                       rng.uniform(5, 40, 20), rng.uniform(-np.pi / 2, np.pi / 2, 20)], axis=-1)
    path = tmp_path / "pcd0001cpos.txt"
    cornell.write_rectangles(path, grasps)
    assert len(path.read_text().splitlines()) == 80
    back, dropped = cornell.read_rectangles(path)
    assert dropped == 0
    np.testing.assert_allclose(back, grasps, atol=1e-9)


def test_cli_prints_json_summary(cornell_root, kosmos_e_annotations):
    result = subprocess.run(
        [sys.executable, "-m", "kosmos_jax.sources.cornell", str(cornell_root),
         "--kosmos-e", str(kosmos_e_annotations)],
        capture_output=True, text=True, cwd=REPO, timeout=120, check=True)
    summary = json.loads(result.stdout)
    counts = [independent_counts(p) for p in all_cpos(cornell_root)]
    negatives = [independent_counts(p) for p in sorted(cornell_root.glob("*/pcd*cneg.txt"))]
    z_lines = (cornell_root / "processedData" / "z.txt").read_text().split("\n")
    local = {p.name[3:7] for p in all_cpos(cornell_root)}
    objects = {l.split()[1] for l in z_lines if l.strip() and l.split()[0] in local}
    assert summary["photos"] == summary["photos_in_full_set"] == 101
    assert summary["positive_rectangles"] == sum(k for k, _ in counts)
    assert summary["nan_rectangles_dropped"] == sum(n for _, n in counts) == 3
    assert summary["negative_rectangles"] == sum(k for k, _ in negatives)
    assert summary["objects"] == len(objects)
    assert summary["photos_with_depth"] == len(list(cornell_root.glob("*/pcd*d.tiff")))
    assert summary["image_shapes"] == {"480x640x3": 101}
    assert summary["kosmos_e_annotated_photos"] == 101
    assert "reading" in result.stderr  # progress goes to stderr, not into the JSON


def test_cli_reports_broken_file(tmp_path):
    (tmp_path / "pcd0001cpos.txt").write_text("1 2\n3 x\n")
    result = subprocess.run([sys.executable, "-m", "kosmos_jax.sources.cornell", str(tmp_path), "--noimages"],
                            capture_output=True, text=True, cwd=REPO, timeout=120)
    assert result.returncode == 1
    assert "pcd0001cpos.txt, line 2" in result.stderr


def test_full_set_ids():
    assert len(cornell.FULL_SET_IDS) == 885
    assert cornell.FULL_SET_IDS[0] == "pcd0100" and cornell.FULL_SET_IDS[-1] == "pcd1034"
    assert list(cornell.FULL_SET_IDS) == sorted(cornell.FULL_SET_IDS)
    assert "pcd0950" not in cornell.FULL_SET_IDS and "pcd0949" in cornell.FULL_SET_IDS
