"""diagnostics.answer_errors: centre distances and angle errors of decoded answers against their targets;
diagnostics.part_oracles: the answers scored again with the centre or the angle from the ground truth."""

import json
import math

import numpy as np
import pytest

from kosmos_jax import geometry
from kosmos_jax.diagnostics import answer_errors as errors_lib
from kosmos_jax.diagnostics import part_oracles as oracles
from kosmos_jax.scoring.instructions import Instruction
from kosmos_jax.scoring.tally import successes
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.workdir.files import RunError

CONFIG = FormatConfig()  # xya, angle code, individual


def location(target, answer):
    cue = "Grasp center point coordinates: "
    return {"part": "location", "target_text": cue + target, "answer": cue + answer}


def angle(target, answer):
    cue = "Grasp rotation angle in radians: "
    return {"part": "angle", "target_text": cue + target, "answer": cue + answer}


def test_each_part_is_measured_against_its_own_target():
    centre, no_angle = errors_lib.answer_errors(location("x_10,y_20", "x_13,y_24"), CONFIG)
    assert centre == pytest.approx(5.0) and math.isnan(no_angle)
    no_centre, wrapped = errors_lib.answer_errors(angle("a_0", "a_255"), CONFIG)
    assert math.isnan(no_centre) and wrapped == pytest.approx(180 / geometry.ANGLE_BINS)  # a_255 is a_0's neighbour
    _, quarter = errors_lib.answer_errors(angle("a_0", "a_64"), CONFIG)
    assert quarter == pytest.approx(45.0)
    assert errors_lib.answer_errors(location("x_10,y_20", "x_10"), CONFIG)[0] == math.inf  # does not parse


def test_the_summary_counts_unparsed_answers_as_misses_and_leaves_them_out_of_the_median():
    rows = [location("x_10,y_20", "x_13,y_24"), location("x_10,y_20", "x_40,y_20"), location("x_10,y_20", "nonsense"),
            angle("a_0", "a_10"), angle("a_0", "a_64")]
    summary = errors_lib.error_summary(rows, CONFIG)
    centre, angles = summary["centre_px"], summary["angle_deg"]
    assert centre == {"answers": 3, "unparsed": 1, "median": 17.5, "within_10_px": round(1 / 3, 4),
                      "within_20_px": round(1 / 3, 4)}
    assert angles["answers"] == 2 and angles["unparsed"] == 0
    assert angles["within_15_deg"] == 0.5 and angles["within_30_deg"] == 0.5
    assert angles["median"] == pytest.approx(np.median([10 * 180 / 256, 45.0]), abs=0.01)
    assert summary["examples"] == 5 and summary["distinct_answers"] == 5
    assert errors_lib.error_summary([location("x_1,y_1", "x_1,y_1")], CONFIG)["angle_deg"] is None


def test_mosaic_answers_are_scored_by_the_quadrant_they_pick():
    half = CONFIG.image_size // 2  # 112: the 224 px mosaic's tiles meet there
    mosaic = [dict(location("x_10,y_20", "x_100,y_100"), scene="multi", kind="multi-name",
                   correct=False),  # target's tile, far off: a hit, scored wrong
              dict(location("x_10,y_20", f"x_{half},y_20"), scene="multi", kind="multi-name"),  # the tile to the right
              dict(location(f"x_{half + 5},y_{half + 5}", "x_220,y_220"), scene="multi",
                   kind="multi-position", correct=True),  # bottom right both, scored right
              dict(location("x_10,y_20", "nonsense"), scene="multi", kind="multi-position"),  # unparsed: a miss
              dict(angle("a_0", "a_0"), scene="multi", kind="multi-name")]  # states no centre: not counted
    single = [dict(location("x_10,y_20", "x_200,y_200"), scene="single")]
    summary = errors_lib.error_summary(mosaic + single, CONFIG)
    assert summary["by_scene"]["multi"]["same_quadrant"] == {"answers": 4, "share": 0.5, "correct_share": 0.5}
    assert summary["by_scene"]["multi"]["same_quadrant_by_kind"] == {
        "multi-name": {"answers": 2, "share": 0.5, "correct_share": 0.0},
        "multi-position": {"answers": 2, "share": 0.5, "correct_share": 1.0}}
    assert "same_quadrant" not in summary["by_scene"]["single"]
    assert summary["by_scene"]["single"]["centre_px"]["answers"] == 1 and summary["examples"] == 6
    assert [errors_lib.quadrant(c, 224) for c in ((0, 0), (112, 0), (0, 112), (111.9, 223))] == [0, 1, 2, 2]


def test_a_run_without_answers_is_told_how_to_make_them(tmp_path):
    with pytest.raises(RunError, match="python -m kosmos_jax.evaluate --workdir="):
        errors_lib.read_answers(tmp_path, 800)
    with pytest.raises(SystemExit, match="not a training run's workdir"):
        errors_lib.main(["--workdir", str(tmp_path)])


def test_scored_reads_the_answers_evaluate_wrote_for_another_source(tmp_path):
    folder = tmp_path / "eval" / "800" / "cornell-synthetic-60-seed7"
    folder.mkdir(parents=True)
    (folder / "answers.jsonl").write_text(json.dumps(angle("a_0", "a_64")) + "\n")
    assert errors_lib.read_answers(tmp_path, 800, "cornell-synthetic-60-seed7") == [angle("a_0", "a_64")]
    with pytest.raises(RunError, match="--cornell="):
        errors_lib.read_answers(tmp_path, 800, "cornell-elsewhere")


# -- part_oracles: the answers scored again with one half from the ground truth ----------------------


def one_instruction(answers, kind="non", parts=("location", "angle")):
    return Instruction(kind, "single", "", {part: index for index, part in enumerate(parts)},
                       np.asarray(answers, np.float32))


TRUTHS = [[50, 50, 20, 10, 0.0], [150, 150, 20, 10, math.pi / 4]]


def test_each_oracle_takes_its_half_from_the_ground_truth_nearest_the_answered_centre():
    instructions = [one_instruction(TRUTHS)] * 4
    grasps = np.array([[52, 50, 0.0],  # right: a hit in all three
                       [52, 50, math.pi / 2],  # right place, wrong angle: only true_angle hits
                       [148, 80, math.pi / 4],  # nearer the second truth, too far: only true_centre hits
                       [np.nan, np.nan, np.nan]])  # did not parse: a miss in all three
    made = oracles.oracle_grasps(instructions, grasps)
    np.testing.assert_allclose(made["true_angle"][:3, 2], [0.0, 0.0, math.pi / 4])
    np.testing.assert_allclose(made["true_centre"][2], [150, 150, math.pi / 4])
    assert np.isnan(made["true_angle"][3]).all() and np.isnan(made["true_centre"][3]).all()
    hits = {name: successes(instructions, grasps_, "honest").tolist() for name, grasps_ in made.items()}
    assert hits == {"model": [True, False, False, False], "true_angle": [True, True, False, False],
                    "true_centre": [True, False, True, False]}


def test_an_instruction_that_states_its_angle_keeps_it():
    instructions = [one_instruction(TRUTHS, kind="angle", parts=("location",))]
    made = oracles.oracle_grasps(instructions, np.array([[52, 50, math.pi / 2]]))
    assert made["true_angle"][0, 2] == pytest.approx(math.pi / 2)  # the instructed angle, not the truth's 0


def test_part_oracles_need_every_answer():
    records = [{"photo_ids": ["p"], "kind": "non", "scene": "non", "instruction": "", "target": 0, "part": part,
                "answers": TRUTHS} for part in ("location", "angle")]
    rows = [{"example": 0, "part": "location", "answer": "Grasp center point coordinates: x_52,y_50"},
            {"example": 1, "part": "angle", "answer": "Grasp rotation angle in radians: a_0"}]
    figures = oracles.part_oracles(records, rows, CONFIG, "honest")
    assert figures["instructions"] == 1 and figures["accuracy"]["model"] == 0.0  # a_0: a quarter turn off
    assert figures["accuracy"]["true_angle"] == 100.0 and figures["by_kind"]["non"]["true_centre"] == 0.0
    with pytest.raises(RunError, match="no answer for 1 test examples"):
        oracles.part_oracles(records, rows[:1], CONFIG, "honest")
