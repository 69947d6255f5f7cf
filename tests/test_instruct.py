"""SINGLE and NON instructions: templates per kind (paper Figs 3-4), per-grasp kinds, errors."""

import json
import re

import numpy as np
import pytest

from kosmos_jax import geometry
from kosmos_jax.annotators.base import MissingWordsError, ObjectWords
from kosmos_jax.annotators.kosmos_e import words_from_entry
from kosmos_jax.annotators import position
from kosmos_jax.instruct import kinds
from kosmos_jax.instruct.sample import View
from kosmos_jax.instruct.single import single_samples

# The sentence patterns of the paper (Figs 3-4) and of the KOSMOS-E code's example files.
FIG_PATTERNS = {
    "angle": r"Grasp the object with a rotation angle of a_(\d+) radians\.",
    "part": r"Grasp the .+ of the .+\.",
    "name": r"Grasp the .+\.",
    "colour": r"Grasp the .+ object( with .+ details?)?\.",  # "with [color] details" (section II)
    "shape": r"Grasp the .+ object\.",
    "purpose": r"Grasp the object for .+\.",
    "position": r"Grasp the object in the (top|middle|bottom|center)( left| middle| right)? section of this image\.",
}

WORDS = ObjectWords(
    name="spoon",
    colour="silver",
    shape="long and thin",
    purpose="scooping food",
    strategy="It is long and thin. Grasp its handle. The gripper should close across the handle.",
    parts=("handle", "bowl", "handle"),
)


def make_view(grasps, words=WORDS, size=224, photo_id="pcd0100", **extra):
    image = np.zeros((size, size, 3), np.uint8)
    return View(photo_id, image, np.asarray(grasps, np.float64), words, **extra)


GRASPS = np.array([
    [40.0, 50.0, 30.0, 10.0, 0.3],
    [60.0, 45.0, 30.0, 10.0, -1.0],
    [44.0, 52.0, 28.0, 12.0, 0.3 + 1e-4],  # same angle code as grasp 0
])


@pytest.mark.parametrize("kind", ["name", "colour", "shape", "purpose", "strategy", "position"])
def test_object_kinds_make_one_sample_with_every_grasp(kind):
    (sample,) = single_samples(make_view(GRASPS), kind)
    assert sample.kind == kind and sample.scene == "single" and sample.answer == "grasp"
    np.testing.assert_array_equal(sample.grasps, GRASPS)
    assert sample.photo_ids == ("pcd0100",)
    if kind == "strategy":
        assert sample.instruction == WORDS.strategy
    else:
        assert re.fullmatch(FIG_PATTERNS[kind], sample.instruction), sample.instruction


def test_templates_fill_the_words():
    view = make_view(GRASPS)
    text = {k: single_samples(view, k)[0].instruction for k in ("name", "colour", "shape", "purpose")}
    assert text == {
        "name": "Grasp the spoon.",
        "colour": "Grasp the silver object.",
        "shape": "Grasp the long and thin object.",
        "purpose": "Grasp the object for scooping food.",
    }
    # centroid (48, 49) of a 224 image: top row (y < 74.67), left column
    assert single_samples(view, "position")[0].instruction == "Grasp the object in the top left section of this image."


def test_angle_instruction_per_grasp_answers_the_centre():
    samples = single_samples(make_view(GRASPS), "angle")
    assert len(samples) == 3
    for i, sample in enumerate(samples):
        code = int(re.fullmatch(FIG_PATTERNS["angle"], sample.instruction).group(1))
        assert code == int(geometry.encode_angle(GRASPS[i, 4]))
        assert sample.answer == "centre"
        np.testing.assert_array_equal(sample.grasps[0], GRASPS[i])
    # grasps 0 and 2 share the angle code, so each is a right answer to the other's instruction
    assert len(samples[0].grasps) == 2 and len(samples[1].grasps) == 1
    np.testing.assert_array_equal(samples[0].grasps[1], GRASPS[2])


def test_part_instruction_per_grasp_follows_grasp_ids():
    samples = single_samples(make_view(GRASPS), "part")
    assert [s.instruction for s in samples] == [
        "Grasp the handle of the spoon.", "Grasp the bowl of the spoon.", "Grasp the handle of the spoon."]
    assert [len(s.grasps) for s in samples] == [2, 1, 2]
    # after augmentation dropped grasp 0, the remaining rows are grasps 1 and 2 of the photo
    dropped = make_view(GRASPS[1:], grasp_ids=np.array([1, 2]))
    assert [s.instruction for s in single_samples(dropped, "part")] == [
        "Grasp the bowl of the spoon.", "Grasp the handle of the spoon."]


def test_verbatim_sentences_win_over_templates():
    entry = {
        "obj_name": "remote control",
        "instruction_name": "Grasp the remote control.",
        "instruction_color": "Grasp the black object.",
        "instruction_shape": "Grasp the rectangular and handheld object with buttons.",
        "instruction_purpose": "Grasp the object for controlling electronic devices wirelessly.",
        "instruction_strategy": "It is rectangular. Grasp along its longest side.",
        "instruction_part": {"0": "Grasp the middle section of the remote control.", "1": "Grasp the end of the remote control."},
    }
    view = make_view(GRASPS[:2], words_from_entry(entry))
    assert single_samples(view, "shape")[0].instruction == entry["instruction_shape"]
    assert single_samples(view, "colour")[0].instruction == "Grasp the black object."
    assert [s.instruction for s in single_samples(view, "part")] == list(entry["instruction_part"].values())


def test_non_sample_has_no_instruction():
    (sample,) = single_samples(make_view(GRASPS), "non")
    assert sample.instruction == "" and sample.scene == "non" and len(sample.grasps) == 3


def test_unknown_kind_names_it_and_lists_valid_kinds():
    with pytest.raises(ValueError, match=r"'texture'.*angle, part, name, colour, shape, purpose, strategy, position"):
        single_samples(make_view(GRASPS), "texture")
    assert kinds.check_kind("color") == "colour"


def test_missing_words_name_the_photo_and_kind():
    with pytest.raises(MissingWordsError, match=r"pcd0199.*'purpose'"):
        single_samples(make_view(GRASPS, ObjectWords(name="cup"), photo_id="pcd0199"), "purpose")
    with pytest.raises(MissingWordsError, match=r"pcd0199.*no annotation"):
        single_samples(make_view(GRASPS, None, photo_id="pcd0199"), "name")
    with pytest.raises(ValueError, match=r"pcd0199.*no grasps"):
        single_samples(make_view(np.zeros((0, 5)), photo_id="pcd0199"), "name")


def test_part_skips_grasps_without_words_but_not_all():
    words = ObjectWords(name="cup", parts=("handle", None, "rim"))
    samples = single_samples(make_view(GRASPS, words), "part")
    assert [s.instruction for s in samples] == ["Grasp the handle of the cup.", "Grasp the rim of the cup."]
    with pytest.raises(MissingWordsError, match="pcd0100.*'part'"):
        single_samples(make_view(GRASPS, ObjectWords(name="cup", parts=(None, None, None))), "part")


@pytest.mark.parametrize("point, word", [
    ((10, 10), "top left"), ((112, 10), "top middle"), ((220, 70), "top right"),
    ((10, 112), "middle left"), ((112, 112), "center"), ((200, 100), "middle right"),
    ((0, 223.9), "bottom left"), ((112, 150), "bottom middle"), ((223.9, 223.9), "bottom right"),
    ((74.66, 74.66), "top left"), ((74.67, 74.67), "center"),  # thirds at 224 / 3 = 74.667
])
def test_grid_words_for_known_centroids(point, word):
    assert position.grid_word(point, 224, 224) == word
    grasps = np.array([[point[0] - 5, point[1], 10, 5, 0.0], [point[0] + 5, point[1], 10, 5, 1.0]])
    assert position.position_word(grasps, 224, 224) == word


def test_real_annotations_make_sentences_of_every_kind(kosmos_e_annotations):
    entries = json.loads(kosmos_e_annotations.read_text())
    assert len(entries) == 885
    off_pattern = []
    for key, entry in entries.items():
        words = words_from_entry(entry)
        view = make_view(np.tile(GRASPS[:1], (len(entry["instruction_part"]), 1)), words, photo_id=key)
        for kind in ("name", "colour", "purpose"):
            text = single_samples(view, kind)[0].instruction
            if not re.fullmatch(FIG_PATTERNS[kind], text.replace("obejct", "object")):  # the file's typo
                off_pattern.append((key, kind, text))
        assert single_samples(view, "strategy")[0].instruction == " ".join(entry["instruction_strategy"].split())
        assert single_samples(view, "shape")[0].instruction.lower().startswith(("grasp the", "grsap the"))
    # The one real sentence off the pattern, used verbatim as the authors wrote it.
    assert off_pattern == [("784", "colour", "Grasp the white and maroon details.")]
