"""The two predictors that learn nothing, scored on exactly the test instructions a trained run was scored on.

    figures = score(records, protocol, image_size)   # {"image_centre": {...}, "gt_mean_oracle": {...}}

The instructions are the evaluation's (scoring.instructions.group_instructions of the test
split's records), the predictors scoring.no_learning's, the metric and protocol the evaluation's
tally: so a row of these sits beside the model's on the same footing. An angle instruction states
its angle; both predictors use it there, as the model's answer does (its answer is the centre only).
`digest` names the test instructions, so runs scored on the same ones can share these rows.
"""

from __future__ import annotations

import hashlib

import numpy as np

from kosmos_jax.scoring import tally
from kosmos_jax.scoring.instructions import Instruction, group_instructions, instructed_angle, text
from kosmos_jax.scoring.no_learning import PREDICTORS, ground_truth_mean, image_centre


def predict(name: str, instructions: list[Instruction], image_size: int) -> np.ndarray:
    """[G, 3] (x, y, theta) of predictor `name` for every instruction."""
    grasps, mask = tally.padded_answers(instructions)
    if name == "image_centre":
        out = image_centre(grasps, mask, image_size)
    elif name == "gt_mean_oracle":
        out = ground_truth_mean(grasps, mask)
    else:
        raise ValueError(f"unknown no-learning predictor {name!r}; expected one of {tuple(PREDICTORS)}")
    out = np.array(out, np.float64)
    for row, instruction in enumerate(instructions):
        if instruction.answer == "centre":
            out[row, 2] = instructed_angle(instruction.instruction)
    return out


def grouped(instructions: list[Instruction], hits: np.ndarray, label) -> dict:
    rows: dict[str, list[int]] = {}
    for index, instruction in enumerate(instructions):
        rows.setdefault(label(instruction), []).append(index)
    return {name: {"accuracy": tally.percent(hits[idx]), "instructions": len(idx)} for name, idx in sorted(rows.items())}


def score(records, protocol: str, image_size: int) -> dict:
    """{predictor: {accuracy (percent), instructions, by_kind, by_scene}} on the instructions of `records`."""
    instructions = group_instructions(records)
    if not instructions:
        raise ValueError("the test split has no instructions to score")
    out = {}
    for name in PREDICTORS:
        hits = tally.successes(instructions, predict(name, instructions, image_size), protocol)
        out[name] = {"accuracy": tally.percent(hits), "instructions": len(instructions),
                     "by_kind": grouped(instructions, hits, lambda i: i.kind),
                     "by_scene": grouped(instructions, hits, lambda i: i.scene)}
    return out


def digest(records) -> str:
    """A short hash of the test instructions: their photos, kind, sentence and answer grasps."""
    hashed = hashlib.sha256()
    for instruction in group_instructions(records):
        first = records[min(instruction.examples.values())]
        photos = "+".join(text(p) for p in first["photo_ids"])
        hashed.update(f"{photos}|{instruction.kind}|{instruction.instruction}|".encode())
        hashed.update(np.round(instruction.answers, 3).astype(np.float32).tobytes())
    return hashed.hexdigest()[:16]
