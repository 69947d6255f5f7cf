"""diagnostics.annotation_draws: a scored synthetic folder's answers against fresh draws of its photos' grasps."""

import pathlib

import numpy as np
import pytest

from kosmos_jax import geometry
from kosmos_jax.diagnostics import annotation_draws
from kosmos_jax.scoring.cornell_examples import honest_views
from kosmos_jax.sources.synthetic import grasps as grasps_lib
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.workdir.files import RunError

CONFIG = FormatConfig()  # xya, angle code, individual
SEED = 5
DRAWS = 6


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> pathlib.Path:
    out = tmp_path_factory.mktemp("draws") / "synthetic"
    scenes.write_dataset(out, photos=4, seed=SEED)
    return out


def records_of(folder) -> tuple[list[dict], list]:
    views, _, _ = honest_views(pathlib.Path(folder), ["non"])
    records = [{"photo_ids": [view.photo_id], "kind": "non", "scene": "single", "instruction": "", "target": 0,
                "part": part, "answers": np.asarray(view.grasps).tolist()}
               for view in views for part in ("location", "angle")]
    return records, views


def answer_rows(grasps) -> list[dict]:
    """The location and angle answers of each (x, y, theta), in the records' order."""
    rows = []
    for number, (x, y, theta) in enumerate(grasps):
        code = int(geometry.encode_angle(theta))
        rows += [{"example": 2 * number, "part": "location", "answer": f"Grasp center point coordinates: x_{x},y_{y}"},
                 {"example": 2 * number + 1, "part": "angle", "answer": f"Grasp rotation angle in radians: a_{code}"}]
    return rows


def test_a_written_photo_is_posed_again_with_its_own_grasps_and_drawn_anew_on_its_object(folder):
    for index in range(4):
        scene, posed = scenes.posed_photo(SEED, index)
        folder_name, stem = scenes.photo_stem(index)
        assert scenes.format_rectangles(scene.positives) == (folder / folder_name / f"{stem}cpos.txt").read_text()
        rng = np.random.default_rng(index)
        for _ in range(5):
            positives, parts = scenes.draw_positives(rng, posed)
            assert len(positives) == len(parts) <= max(scenes.POSITIVES[0])
            centres = np.array([grasp[:2] for grasp in positives]).reshape(-1, 2)
            assert grasps_lib.inside(posed.masks.object, centres).all()


def test_an_answer_on_a_written_grasp_hits_and_one_off_the_object_misses_every_draw(folder):
    records, views = records_of(folder)
    on_grasp = [(int(round(v.grasps[0][0])), int(round(v.grasps[0][1])), float(v.grasps[0][4])) for v in views]
    figures = annotation_draws.annotation_draws(records, answer_rows(on_grasp), CONFIG, folder, draws=DRAWS,
                                                candidates=16)
    assert figures["instructions"] == len(views) == 4
    assert figures["accuracy"]["model"] == 100.0
    assert 0.0 < figures["accuracy"]["model_expected"] <= 100.0
    for name in ("target_draw", "parts_draw", "consensus_draw", "best_expected", "best"):
        assert 0.0 <= figures["accuracy"][name] <= 100.0
    assert sum(row["instructions"] for row in figures["categories"].values()) == 4

    corner = [(0, 0, 0.0)] * len(views)  # the view's corner: no object lies there
    missed = annotation_draws.annotation_draws(records, answer_rows(corner), CONFIG, folder, draws=DRAWS, candidates=16)
    assert missed["accuracy"]["model"] == missed["accuracy"]["model_expected"] == 0.0
    # the draws and the best answer do not depend on the model's answers
    for name in ("target_draw", "parts_draw", "consensus_draw", "best_expected", "best"):
        assert missed["accuracy"][name] == figures["accuracy"][name]


def test_the_best_answer_hits_more_fresh_draws_than_a_random_target_does(folder):
    records, views = records_of(folder)
    rows = answer_rows([(0, 0, 0.0)] * len(views))
    figures = annotation_draws.annotation_draws(records, rows, CONFIG, folder, draws=40, candidates=64)
    # the best of 64 candidates, chosen on draws it is not scored on, against one target drawn at random
    assert figures["accuracy"]["best_expected"] > figures["accuracy"]["target_draw"]


def test_a_folder_that_the_generator_did_not_write_is_refused(folder, tmp_path):
    records, views = records_of(folder)
    rows = answer_rows([(0, 0, 0.0)] * len(views))
    with pytest.raises(RunError, match="synthetic_meta.json not found"):
        annotation_draws.annotation_draws(records, rows, CONFIG, tmp_path, draws=DRAWS)
    moved = [dict(record, answers=(np.asarray(record["answers"]) + [3, 0, 0, 0, 0]).tolist()) for record in records]
    with pytest.raises(RunError, match="does not have the folder's grasps"):
        annotation_draws.annotation_draws(moved, rows, CONFIG, folder, draws=DRAWS)
    with pytest.raises(RunError, match="draws must be >= 2"):
        annotation_draws.annotation_draws(records, rows, CONFIG, folder, draws=1)


def test_the_command_asks_for_a_scored_folder(tmp_path):
    with pytest.raises(SystemExit, match="give --scored=cornell-NAME: only a scored synthetic folder can be drawn again"):
        annotation_draws.main([f"--workdir={tmp_path}"])
