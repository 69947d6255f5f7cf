"""evaluate.answer_errors: centre distances and angle errors of decoded answers against their targets."""

import math

import numpy as np
import pytest

from kosmos_jax import geometry
from kosmos_jax.evaluate import answer_errors as errors_lib
from kosmos_jax.evaluate.run import RunError
from kosmos_jax.text.formatter import FormatConfig

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


def test_a_run_without_answers_is_told_how_to_make_them(tmp_path):
    with pytest.raises(RunError, match="python -m kosmos_jax.evaluate --workdir="):
        errors_lib.read_answers(tmp_path, 800)
    with pytest.raises(SystemExit, match="not a training run's workdir"):
        errors_lib.main(["--workdir", str(tmp_path)])
