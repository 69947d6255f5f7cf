"""scripts/paired_runs.py: two runs' answers to the same instructions, counted pair by pair."""

import importlib.util
import json
import math
import pathlib

import pytest

from kosmos_jax.workdir.files import RunError

SCRIPT = pathlib.Path(__file__).resolve().parents[1] / "scripts" / "paired_runs.py"
spec = importlib.util.spec_from_file_location("paired_runs", SCRIPT)
paired_runs = importlib.util.module_from_spec(spec)
spec.loader.exec_module(paired_runs)


def rows(rights: list[bool], scene: str = "single") -> list[dict]:
    """evaluate's answer rows of one NON instruction a photo, each in two parts, the same photo twice in a row
    for the last two (as two views of one photo would be)."""
    out = []
    for number, right in enumerate(rights):
        photo = f"p{min(number, len(rights) - 2)}"
        for part in ("location", "angle"):
            out.append({"example": len(out), "kind": "non", "scene": scene, "part": part, "photo_ids": [photo],
                        "instruction": "", "target_text": f"t{number}{part}", "correct": right})
    return out


def test_each_instruction_counts_once_and_the_discordant_pairs_give_mcnemars_z():
    baseline = paired_runs.instruction_results(rows([True, True, False, False, True]))
    candidate = paired_runs.instruction_results(rows([True, False, True, True, True]))
    assert sorted(baseline) == [0, 2, 4, 6, 8]  # the repeated photo still starts a new instruction
    (line,) = paired_runs.paired(baseline, candidate)
    assert line == {"scene": "single", "instructions": 5, "baseline_right": 3, "candidate_right": 4,
                    "only_candidate": 2, "only_baseline": 1, "mcnemar_z": round(1 / math.sqrt(3), 2)}


def test_runs_that_answered_other_instructions_are_refused():
    baseline = paired_runs.instruction_results(rows([True, False]))
    with pytest.raises(RunError, match="did not answer the same instructions"):
        paired_runs.paired(baseline, paired_runs.instruction_results(rows([True, False, True])))
    other = rows([True, False])
    other[2]["target_text"] = "another target"
    with pytest.raises(RunError, match="did not answer the same instructions"):
        paired_runs.paired(baseline, paired_runs.instruction_results(other))


def test_the_zoomed_mosaics_are_paired_by_their_zoomed_answers():
    def mosaic_rows(first: list[bool], zoomed: list[bool]) -> list[dict]:
        out = rows(first, scene="multi")
        for row in out:
            row["zoom_correct"] = zoomed[int(row["target_text"][1])]
        return rows([True], scene="single") + out  # a single photo's rows have no zoom_correct

    baseline = paired_runs.instruction_results(mosaic_rows([False, False, True], [True, False, True]), zoomed=True)
    candidate = paired_runs.instruction_results(mosaic_rows([False, False, False], [True, True, False]), zoomed=True)
    (line,) = paired_runs.paired(baseline, candidate)
    assert line == {"scene": "multi, zoomed", "instructions": 3, "baseline_right": 2, "candidate_right": 2,
                    "only_candidate": 1, "only_baseline": 1, "mcnemar_z": 0.0}
    with pytest.raises(RunError, match="score the run with evaluate --mosaic_zoom"):
        paired_runs.instruction_results(rows([True, False]), zoomed=True)


def test_an_answers_file_is_read_as_a_side(tmp_path):
    written = rows([True, False, True])
    path = tmp_path / "answers.jsonl"
    path.write_text("".join(json.dumps(row) + "\n" for row in written))
    assert paired_runs.answers_of(path, None, "ignored") == written
    with pytest.raises(RunError, match="holds no checkpoint"):
        paired_runs.answers_of(tmp_path / "not_a_run", None, "cornell-x")
