"""`evaluate --overlays=N`: the first N scored views of each instruction kind, drawn as the paper's
Fig. 7 (scoring.drawing): the constrained answer's grasp in red, the instruction's ground truths
in blue, the instruction beneath; one grid per kind, WORKDIR/eval/STEP/overlays/KIND.png.

Drawn from what the evaluation wrote (its answers, one row per example) and the same examples it
scored, so nothing is decoded again. The predicted grasp's w, h are the answer's when it states
them, else borrowed from the ground truths as the protocol's metric borrows them.
"""

from __future__ import annotations

import pathlib
from collections.abc import Sequence

import numpy as np

from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.drawing import NO_INSTRUCTION, grid, overlay, write_png
from kosmos_jax.scoring.grasp_size import borrowed_size
from kosmos_jax.scoring.instructions import combine, group_instructions
from kosmos_jax.text.formatter import parse_target
from kosmos_jax.workdir.run import open_run

ZOOM = 2  # 224 views drawn at 448, so that the captions are legible
COLUMNS = 4


def _examples(run, results: dict):
    """The scored examples, indexable for records with their "image"."""
    if "cornell" in results:
        return cornell_examples(results["cornell"], run.tokenizer, run.format_config, results["kinds"]).records
    return run.split(results["split"])


def predicted_grasp(instruction, rows: dict[int, dict], config, protocol: str) -> np.ndarray:
    """(x, y, w, h, theta) of an instruction's constrained answers in view pixels (NaN if unparsed)."""
    parsed = {part: parse_target(rows[i]["answer"], part, config) for part, i in instruction.examples.items()}
    x, y, theta = combine(instruction, parsed)
    stated = parsed["grasp" if "grasp" in parsed else "location"].grasp[2:4]
    width, jaw = stated if np.isfinite(stated).all() else borrowed_size(instruction.answers, protocol)
    return np.array([x, y, width, jaw, theta])


def write_overlays(workdir, results: dict, rows: Sequence[dict], folder, count: int) -> list[pathlib.Path]:
    """One PNG grid per instruction kind under folder/overlays; the paths written."""
    if count < 1:
        return []
    if rows and "answer" not in rows[0]:
        raise ValueError("--overlays draws KOSMOS-E's answers; a baseline run's grasps are not drawn")
    run = open_run(workdir)
    examples = _examples(run, results)
    answered = {row["example"]: row for row in rows}
    records = getattr(examples, "examples", examples)
    tiles: dict[str, list[np.ndarray]] = {}
    for instruction in group_instructions(records):
        chosen = tiles.setdefault(instruction.kind, [])
        if len(chosen) >= count or not all(i in answered for i in instruction.examples.values()):
            continue
        grasp = predicted_grasp(instruction, answered, run.format_config, results["protocol"])
        image = examples[min(instruction.examples.values())]["image"]
        chosen.append(overlay(image, grasp, instruction.answers, instruction.instruction or NO_INSTRUCTION, zoom=ZOOM))
    out = pathlib.Path(folder) / "overlays"
    return [write_png(out / f"{kind}.png", grid(kind_tiles, COLUMNS)) for kind, kind_tiles in tiles.items() if kind_tiles]
