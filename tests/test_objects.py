"""Cornell's z.txt object map."""

import shutil

import pytest

from kosmos_jax.sources import cornell, objects, text_file


def test_real_map_deduplicated(cornell_root):
    path = cornell_root / "processedData" / "z.txt"
    lines = [l.split() for l in path.read_text().splitlines() if l.strip()]
    mapping = objects.read_object_map(path)
    assert len(lines) == 7037  # one per labelled rectangle of the old round
    assert len(mapping) == len({l[0] for l in lines}) == 1035
    assert all(photo_id in mapping for photo_id in cornell.FULL_SET_IDS)
    for image, object_id, category, _ in lines[::97]:
        assert mapping[f"pcd{image}"] == (int(object_id), category)
    assert mapping["pcd0000"] == (0, "Aluminum_Can")


def test_found_under_root_or_flat(tmp_path, cornell_root):
    assert objects.find_object_map(cornell_root) == cornell_root / "processedData" / "z.txt"
    assert objects.find_object_map(tmp_path) is None
    shutil.copy(cornell_root / "processedData" / "z.txt", tmp_path)
    assert objects.find_object_map(tmp_path) == tmp_path / "z.txt"


def test_reader_attaches_or_not(tmp_path, cornell_root):
    shutil.copy(cornell_root / "01" / "pcd0100cpos.txt", tmp_path)
    assert cornell.load_photos(tmp_path, load_images=False)[0].object_id is None
    (tmp_path / "map.txt").write_text("0100 7 Mug pcdb_0001\n")
    photo = cornell.load_photos(tmp_path, load_images=False, object_map=tmp_path / "map.txt")[0]
    assert (photo.object_id, photo.category) == (7, "Mug")
    photo = cornell.load_photos(tmp_path, load_images=False, object_map=None)[0]
    assert photo.object_id is None


@pytest.mark.parametrize("text, line", [
    ("0100 1 Mug pcdb_0001\n0101 1 Mug\n", 2),
    ("0100 1 Mug pcdb_0001\n\nx100 1 Mug pcdb_0001\n", 3),
    ("0100 1 Mug pcdb_0001\n0100 2 Bowl pcdb_0001\n", 2),  # one image, two objects
    ("0100 1 Mug pcdb_0001\n\u0661\u0660\u0660 1 Mug pcdb_0001\n", 2),  # Arabic-Indic digits: int() reads them
    ("0100 1_0 Mug pcdb_0001\n", 1),
    ("0100 -1 Mug pcdb_0001\n", 1),
    ("0100 +1 Mug pcdb_0001\n", 1),
])
def test_bad_lines_name_file_and_line(tmp_path, text, line):
    path = tmp_path / "z.txt"
    path.write_text(text)
    with pytest.raises(objects.ObjectMapFormatError) as error:
        objects.read_object_map(path)
    assert str(path) in str(error.value) and f"line {line}" in str(error.value)


def test_ascii_integers_are_ascii_digits_only():
    assert all(text_file.is_ascii_integer(f) for f in ("0", "12", "0042"))
    assert not any(text_file.is_ascii_integer(f) for f in ("", "-1", "+1", "1_0", "1.0", " 1", "\u0661\u0662", "\uff11"))


def test_repeated_identical_lines_are_one_entry():
    mapping = objects.parse_object_map("0100 1 Mug b\r\n0100 1 Mug b\r\n0101 2 Bowl b")
    assert mapping == {"pcd0100": (1, "Mug"), "pcd0101": (2, "Bowl")}


def test_broken_copies_of_the_real_map_name_file_line_and_column(tmp_path, cornell_root):
    lines = (cornell_root / "processedData" / "z.txt").read_bytes().split(b"\n")
    path = tmp_path / "z.txt"
    bad = list(lines)
    bad[41] = bad[41][:5] + b"\xff" + bad[41][5:]  # line 42, column 6: a Latin-1 byte
    path.write_bytes(b"\n".join(bad))
    with pytest.raises(objects.ObjectMapFormatError, match=r"z\.txt, line 42, column 6: not UTF-8 text \(byte 0xff\)"):
        objects.read_object_map(path)
    bad = list(lines)
    bad[9] = "\u0661\u0660\u0660 1 Mug pcdb_0001".encode()  # Arabic-Indic digits pass str.isdigit()
    path.write_bytes(b"\n".join(bad))
    with pytest.raises(objects.ObjectMapFormatError, match=r"z\.txt, line 10: image and object id must be integers"):
        objects.read_object_map(path)
    path.write_bytes(b"\xef\xbb\xbf" + b"\n".join(lines))  # a byte-order mark is not part of the first image id
    assert objects.read_object_map(path) == objects.read_object_map(cornell_root / "processedData" / "z.txt")
