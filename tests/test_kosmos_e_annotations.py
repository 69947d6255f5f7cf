"""KOSMOS-E instruction annotations aligned to Cornell photos."""

import dataclasses
import json

import pytest

from kosmos_jax.sources import cornell, kosmos_e_annotations as ke


@pytest.fixture
def annotations(kosmos_e_annotations):
    return ke.read_annotations(kosmos_e_annotations)


def test_keys_follow_full_sorted_set_not_local_subset(annotations, kosmos_e_annotations):
    raw = json.loads(kosmos_e_annotations.read_text())
    # pcd0312 is the 213th photo of the full set (key "212"), though it is the 101st present here.
    assert cornell.list_photo_ids(kosmos_e_annotations.parents[1] / "cornell").index("pcd0312") == 100
    assert annotations.entries["pcd0312"] == raw["212"]
    assert annotations.entries["pcd1000"] == raw[str(850)]
    assert annotations.entries["pcd0100"] == raw["0"]


def test_every_local_photo_aligns(cornell_root, annotations):
    photos = ke.attach_all(cornell.load_photos(cornell_root, load_images=False), annotations)
    for photo in photos:
        a = photo.annotations
        assert set(a) == {"name", "colour", "shape", "purpose", "strategy", "parts", "instructions"}
        assert len(a["parts"]) == len(photo.grasps)
        raw_parts = a["instructions"]["instruction_part"]
        assert a["parts"] == [raw_parts[str(i)] for i in range(len(raw_parts))]
        assert a["colour"] == a["instructions"]["instruction_color"]
    nan_photo = next(p for p in photos if p.id == "pcd0132")
    assert nan_photo.nan_dropped == 2 and len(nan_photo.annotations["parts"]) == len(nan_photo.grasps)
    first = photos[0]
    assert first.annotations["name"] == "remote control"
    assert first.annotations["colour"] == "Grasp the black object."


def test_attach_is_pure_and_keeps_other_annotations(cornell_root, annotations):
    photo = cornell.load_photos(cornell_root, load_images=False, ids=["pcd0100"])[0]
    photo.annotations["mine"] = 1
    attached = annotations.attach(photo)
    assert attached.annotations["mine"] == 1 and "name" not in photo.annotations


def test_count_mismatch_names_the_photo(cornell_root, annotations):
    photo = cornell.load_photos(cornell_root, load_images=False, ids=["pcd0165"])[0]
    short = dataclasses.replace(photo, grasps=photo.grasps[:-1])
    with pytest.raises(ke.AnnotationMismatchError, match="pcd0165"):
        annotations.attach(short)


def test_object_names_file_agrees(kosmos_e_annotations, annotations):
    names = ke.read_object_names(kosmos_e_annotations.with_name("obj_names.txt"))
    assert all(names[pid] == annotations.entries[pid]["obj_name"] for pid in cornell.FULL_SET_IDS)


def test_malformed_files(tmp_path, kosmos_e_annotations):
    raw = json.loads(kosmos_e_annotations.read_text())
    del raw["884"]
    with pytest.raises(ke.AnnotationMismatchError, match="884"):
        ke.parse_annotations(raw, "x.json")
    raw = json.loads(kosmos_e_annotations.read_text())
    del raw["5"]["instruction_color"]
    with pytest.raises(ke.AnnotationMismatchError, match="pcd0105"):
        ke.parse_annotations(raw, "x.json")


def test_broken_copies_name_file_line_and_column(tmp_path, kosmos_e_annotations):
    text = kosmos_e_annotations.read_text()
    path = tmp_path / "instructions-original.json"
    path.write_text(text[: len(text) // 2])  # truncated mid-file
    with pytest.raises(ke.AnnotationMismatchError, match=r"instructions-original\.json, line \d+, column \d+: not valid JSON"):
        ke.read_annotations(path)
    lines = text.split("\n")
    assert len(lines) > 5
    lines[3] = "}" + lines[3]  # a stray brace at the start of line 4
    path.write_text("\n".join(lines))
    with pytest.raises(ke.AnnotationMismatchError, match=r"instructions-original\.json, line 4, column 1: not valid JSON"):
        ke.read_annotations(path)
    lines = text.encode().split(b"\n")
    lines[2] = b"  \xff" + lines[2]
    path.write_bytes(b"\n".join(lines))
    with pytest.raises(ke.AnnotationMismatchError, match=r"instructions-original\.json, line 3, column 3: not UTF-8"):
        ke.read_annotations(path)
    path.write_text("[1, 2]")
    with pytest.raises(ke.AnnotationMismatchError, match="expected a JSON object"):
        ke.read_annotations(path)
    names = tmp_path / "obj_names.txt"
    names.write_bytes(kosmos_e_annotations.with_name("obj_names.txt").read_bytes().replace(b"\n", b"\n\x80", 1))
    with pytest.raises(ke.AnnotationMismatchError, match=r"obj_names\.txt, line 2, column 1: not UTF-8"):
        ke.read_object_names(names)
