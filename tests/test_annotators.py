"""Annotators: KOSMOS-E file, synthetic metadata, rule-based colour and position."""

import json

import cv2
import numpy as np
import pytest

from kosmos_jax.annotators import kosmos_e, rules, synthetic
from kosmos_jax.annotators.base import MissingWordsError, ObjectWords, colour_terms, require, terms
from kosmos_jax.sources.photo import Photo
from kosmos_jax.instruct.sample import View
from kosmos_jax.instruct.single import single_samples

ENTRY = {
    "obj_name": "a pair of sunglasses",
    "instruction_name": "The object in this image is swimming goggles.",
    "instruction_color": "Grasp the black object with yellow details..",
    "instruction_shape": "Grsap the rectangular or box-shaped object with a lens and controls.",
    "instruction_purpose": "Grasp the obejct for wearing and blocking sunlight.",
    "instruction_strategy": "It is symmetric. Grasp the bridge.",
    "instruction_part": {"0": "Grasp the bridge of the sunglasses.", "1": "I'm sorry, I cannot assist with that request.",
                         "2": "Grasp the whole object."},
}


def test_kosmos_e_words_and_junk():
    words = kosmos_e.words_from_entry(ENTRY)
    assert words.name == "a pair of sunglasses"
    assert words.colour == "black with yellow details" and colour_terms(words.colour) == {"black", "yellow"}
    assert words.shape == "rectangular or box-shaped"
    assert words.purpose == "wearing and blocking sunlight"
    assert words.parts == ("bridge", None, None)
    assert "name" not in words.sentences  # not an instruction: the template is used instead
    assert words.sentences["part"] == ("Grasp the bridge of the sunglasses.", None, "Grasp the whole object.")
    assert kosmos_e.junk_sentences(ENTRY) == [
        ("name", "The object in this image is swimming goggles."),
        ("part", "I'm sorry, I cannot assist with that request.")]
    view = View("pcd0107", np.zeros((224, 224, 3), np.uint8), np.tile([[50.0, 50, 20, 10, 0]], (3, 1)), words)
    assert single_samples(view, "name")[0].instruction == "Grasp the a pair of sunglasses."
    assert single_samples(view, "colour")[0].instruction == "Grasp the black object with yellow details."
    assert [s.instruction for s in single_samples(view, "part")] == [
        "Grasp the bridge of the sunglasses.", "Grasp the whole object."]


def test_terms_of_a_phrase():
    assert terms("The Navy-Blue  driver's cap.", {"the"}) == ("navy-blue", "driver's", "cap")
    assert terms("cap and cap", ()) == ("cap", "and", "cap")  # order and repeats kept
    assert colour_terms("Grey and light-blue, with some RED accents.") == {"gray", "light-blue", "red"}


def test_kosmos_e_reader_annotations_give_the_same_words():
    reader_style = {"name": "a pair of sunglasses", "colour": ENTRY["instruction_color"],
                    "parts": list(ENTRY["instruction_part"].values()), "instructions": ENTRY}
    assert kosmos_e.words_from_entry(reader_style) == kosmos_e.words_from_entry(ENTRY)


def test_kosmos_e_photo_checks_part_count():
    photo = Photo("pcd0107", np.zeros((4, 4, 3), np.uint8), None, np.zeros((2, 5)), annotations=dict(ENTRY))
    with pytest.raises(ValueError, match=r"pcd0107.*3 part instructions.*2 grasps"):
        kosmos_e.words_from_photo(photo)
    with pytest.raises(ValueError, match=r"pcd0108.*no KOSMOS-E annotations"):
        kosmos_e.words_from_photo(Photo("pcd0108", np.zeros((4, 4, 3), np.uint8), None, np.zeros((2, 5))))


def test_real_kosmos_e_file_words(kosmos_e_annotations):
    entries = json.loads(kosmos_e_annotations.read_text())
    words = {key: kosmos_e.words_from_entry(entry) for key, entry in entries.items()}
    assert words["0"].name == "remote control" and words["0"].colour == "black"
    assert words["500"].colour == "green, yellow, and silver"
    assert colour_terms(words["500"].colour) == {"green", "yellow", "silver"}
    assert all(w.name and w.colour and w.shape and w.purpose and w.strategy for w in words.values())
    junk = [j for entry in entries.values() for j in kosmos_e.junk_sentences(entry)]
    assert sum(kind == "part" for kind, _ in junk) == 22 and sum(kind == "name" for kind, _ in junk) == 8


def test_synthetic_metadata_words(tmp_path):
    from kosmos_jax.sources.synthetic import scenes as synthetic_data

    synthetic_data.write_dataset(tmp_path / "syn", 3, 5)
    meta = json.loads((tmp_path / "syn" / "synthetic_meta.json").read_text())["photos"]
    words = synthetic.read_meta_words(tmp_path / "syn")
    assert set(words) == set(meta)
    for photo_id, record in meta.items():
        w = words[photo_id]
        assert (w.name, w.colour, w.purpose, w.strategy) == (
            record["name"], record["colour_phrase"], record["purpose"], record["strategy"])
        assert w.parts == tuple(record["grasp_parts"])
        assert w.sentences["shape"] == f"Grasp the {record['shape_phrase']}."
        cpos = (tmp_path / "syn" / record["folder"] / f"{photo_id}cpos.txt").read_text().split()
        assert len(w.parts) == len(cpos) // 8  # one part per positive rectangle
    with pytest.raises(ValueError, match=r"pcd9.*lacks \['strategy'"):
        synthetic.words_from_meta({k: v for k, v in next(iter(meta.values())).items() if k != "strategy"}, "pcd9")
    document = {"photos": meta}
    assert synthetic.words_from_document(document, "here.json") == words
    with pytest.raises(ValueError, match=r"here.json: no 'photos' object"):
        synthetic.words_from_document({"0": {}}, "here.json")


def textured_background(rng, size=224):
    yy, xx = np.mgrid[:size, :size]
    base = np.array([205, 195, 175])  # a beige table
    checker = ((xx // 7 + yy // 7) % 2 * 14)[..., None]
    grain = rng.integers(-8, 9, (size, size, 3))
    return np.clip(base + checker + grain, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("rgb, name", [
    ((30, 70, 210), "blue"), ((200, 30, 30), "red"), ((40, 150, 60), "green"), ((240, 215, 40), "yellow"),
    ((25, 25, 25), "black"), ((120, 50, 160), "purple")])
def test_rule_colour_of_a_blob_on_a_textured_background(rgb, name):
    rng = np.random.default_rng(sum(rgb))
    image = textured_background(rng)
    cv2.ellipse(image, (120, 100), (40, 22), 30, 0, 360, rgb, -1)
    noisy = np.clip(image.astype(int) + rng.integers(-6, 7, image.shape) * (image != textured_background(
        np.random.default_rng(sum(rgb))))[..., :1], 0, 255).astype(np.uint8)
    assert rules.colour_names(noisy) == [name]
    grasps = np.array([[120.0, 100.0, 50.0, 20.0, -0.5]])
    assert rules.words_from_pixels(noisy, grasps) == ObjectWords(colour=name)


def test_rule_colour_of_a_two_colour_object():
    image = textured_background(np.random.default_rng(3))
    cv2.rectangle(image, (60, 80), (120, 140), (30, 70, 210), -1)
    cv2.rectangle(image, (120, 80), (170, 140), (200, 30, 30), -1)
    assert set(rules.colour_names(image)) == {"blue", "red"}
    assert rules.words_from_pixels(image).colour == "blue and red"  # blue covers more pixels
    assert rules.colour_phrase(["green", "yellow", "silver"]) == "green, yellow, and silver"


def test_rule_colour_of_a_many_coloured_object_is_its_most_frequent_colour():
    # six stripes, none covering 20% of the object: the widest (red) names it
    image = textured_background(np.random.default_rng(4))
    x = 40
    for width, rgb in ((28, (200, 30, 30)), (25, (30, 70, 210)), (24, (40, 150, 60)), (23, (240, 215, 40)),
                       (22, (120, 50, 160)), (21, (25, 25, 25))):
        cv2.rectangle(image, (x, 80), (x + width - 1, 150), rgb, -1)
        x += width
    assert rules.colour_names(image) == ["red"]
    assert rules.words_from_pixels(image).colour == "red"
    assert rules.colour_names(image, min_share=0.1) == ["red", "blue", "green"]  # the rule itself is unchanged


def test_empty_words_are_no_words():
    assert not ObjectWords(colour="").has("colour") and not ObjectWords(colour="  ").has("colour")
    assert not ObjectWords(sentences={"colour": ""}).has("colour")
    assert not ObjectWords(parts=("", None)).has("part")
    assert ObjectWords(colour="red").has("colour") and ObjectWords(parts=(None, "handle")).has("part")


def test_unknown_words_say_why():
    words = ObjectWords(name="cup", unknown={"colour": "no pixel differs from the background"})
    assert not words.has("colour") and require(words, "name", "pcd0104") is words
    with pytest.raises(MissingWordsError, match=r"'pcd0104' has no 'colour' words \(no pixel differs"):
        require(words, "colour", "pcd0104")


def test_rule_colour_errors():
    with pytest.raises(rules.NoColourError, match="no pixel differs"):
        rules.colour_names(np.full((64, 64, 3), 128, np.uint8))
    with pytest.raises(ValueError, match=r"\[H, W, 3\].*\(64, 64\)"):
        rules.colour_names(np.zeros((64, 64), np.uint8))


def test_rule_position_from_grasps():
    grasps = np.array([[180.0, 30.0, 20, 10, 0.0], [200.0, 50.0, 20, 10, 1.0]])  # centroid (190, 40)
    assert rules.position_from_grasps(grasps, 224, 224) == "top right"
    assert rules.position_from_grasps(grasps, 640, 480) == "top left"  # 190 < 640 / 3
    with pytest.raises(ValueError, match="at least one grasp"):
        rules.position_from_grasps(np.zeros((0, 5)), 224, 224)
