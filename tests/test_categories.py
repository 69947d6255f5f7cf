"""diagnostics.categories: a scored synthetic folder's single-photo answers split by object category."""

import json
import math

import pytest

from kosmos_jax import geometry
from kosmos_jax.diagnostics import categories
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.workdir.files import RunError

CONFIG = FormatConfig()  # xya, angle code, individual
TRUTHS = [[50, 50, 20, 10, 0.0], [150, 150, 20, 10, math.pi / 4]]


def photo_records(photo: str, scene: str = "non") -> list[dict]:
    return [{"photo_ids": [photo], "kind": "non", "scene": scene, "instruction": "", "target": 0, "part": part,
             "answers": TRUTHS} for part in ("location", "angle")]


def answers(first: int, x: int, y: int, theta: float) -> list[dict]:
    code = int(geometry.encode_angle(theta))
    return [{"example": first, "part": "location", "answer": f"Grasp center point coordinates: x_{x},y_{y}"},
            {"example": first + 1, "part": "angle", "answer": f"Grasp rotation angle in radians: a_{code}"}]


def test_each_category_gets_its_photos_accuracy_oracles_and_centre_distance():
    records = photo_records("a") + photo_records("b") + photo_records("c")
    rows = answers(0, 52, 50, 0.0) + answers(2, 50, 54, math.pi / 2) + answers(4, 150, 150, math.pi / 4)
    # a hit; the right place at a quarter turn off (only true_angle hits); a hit
    figures = categories.by_category(records, rows, CONFIG, "honest", {"a": "Mug", "b": "Mug", "c": "Tape"})
    assert figures["Mug"] == {"instructions": 2, "model": 50.0, "true_angle": 100.0, "true_centre": 50.0,
                              "median_centre_px": 3.0}
    assert figures["Tape"]["instructions"] == 1 and figures["Tape"]["model"] == 100.0
    assert figures["Tape"]["median_centre_px"] == 0.0


def test_mosaic_instructions_are_left_out_and_an_unknown_photo_is_refused():
    records = photo_records("a") + photo_records("m", scene="multi")
    rows = answers(0, 52, 50, 0.0) + answers(2, 52, 50, 0.0)
    assert list(categories.by_category(records, rows, CONFIG, "honest", {"a": "Mug"})) == ["Mug"]
    with pytest.raises(RunError, match=r"1 scored photos \(first a\) are not in the folder's synthetic_meta.json"):
        categories.by_category(records[:2], rows[:2], CONFIG, "honest", {})


def test_the_categories_come_from_a_synthetic_folder_and_nowhere_else(tmp_path):
    scenes.write_dataset(tmp_path / "made", photos=3, seed=5)
    written = json.loads((tmp_path / "made" / "synthetic_meta.json").read_text())["photos"]
    assert categories.photo_categories(tmp_path / "made") == {p: about["category"] for p, about in written.items()}
    assert len(written) == 3
    with pytest.raises(RunError, match="synthetic_meta.json not found.*categories are known only for folders written by"):
        categories.photo_categories(tmp_path)
