"""The mosaic zoom's variants, a probe: which window and which enlargement (scoring/zoom.py chose on it).

    python scripts/zoom_variants.py --workdir=RUN --cornell=datasets/synthetic-300-seed7 \
        [--window=quadrant|centred] [--interpolation=linear|cubic] [>> RECORDS.jsonl]

Decodes the run's answers to every photo's NON and multi-object instructions of the folder (one pass,
as the evaluate command does), then answers each mosaic instruction again as NON on a window of half
the mosaic's side, enlarged 2x: `quadrant`, the quadrant holding the first answer's centre (what
the evaluate command's --mosaic_zoom does); `centred`, the window centred on that answer, kept
inside the mosaic. Prints one JSON line: single photos and mosaics in
one pass, the mosaics zoomed, the mosaic instructions right only zoomed and only in one pass, and
per kind (instructions, right in one pass, right zoomed).
"""

import argparse
import json

import cv2
import numpy as np

from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_decoding import chosen_windows, configured_windows
from kosmos_jax.predict.asking import ask
from kosmos_jax.predict.framing import Framing
from kosmos_jax.predict.predictor import GraspPredictor
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.workdir.run import open_run
from kosmos_jax.workdir.sizes import run_grasp_size
from paired_runs import mcnemar_z  # scripts/, this script's folder

ENLARGEMENTS = {"cubic": cv2.INTER_CUBIC, "linear": cv2.INTER_LINEAR}


def window_corner(x: float, y: float, half: int, window: str) -> tuple[int, int]:
    if not (np.isfinite(x) and np.isfinite(y)):
        x = y = half
    if window == "quadrant":
        return (0 if x < half else half), (0 if y < half else half)
    return int(np.clip(round(x - half / 2), 0, half)), int(np.clip(round(y - half / 2), 0, half))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--cornell", required=True)
    parser.add_argument("--window", choices=("quadrant", "centred"), default="quadrant")
    parser.add_argument("--interpolation", choices=sorted(ENLARGEMENTS), default="linear")
    args = parser.parse_args()
    run, mesh = open_run(args.workdir), make_mesh(1, -1, 1)
    step, params = run.params(None, mesh)
    records = cornell_examples(args.cornell, run.tokenizer, run.format_config, ("non", "multi")).records
    windows = chosen_windows(configured_windows(run.config))
    evaluation = GraspEvaluation(run.model_config, mesh, records, run.tokenizer, run.format_config, "honest", **windows)
    held = evaluation.answers(params)
    first, hits_first = evaluation.grasps(held), evaluation.successes(held)
    predictor = GraspPredictor(run.model_config, params, run.tokenizer, run.format_config, protocol="honest",
                               grasp_size=run_grasp_size(run), mesh=mesh, **windows)
    mosaics = [g for g, instruction in enumerate(evaluation.instructions) if instruction.scene == "multi"]
    views, corners = [], []
    for g in mosaics:
        image = records[min(evaluation.instructions[g].examples.values())]["image"]
        half = image.shape[0] // 2
        ox, oy = window_corner(first[g][0], first[g][1], half, args.window)
        tile = np.ascontiguousarray(image[oy:oy + half, ox:ox + half])
        views.append(cv2.resize(tile, image.shape[:2][::-1], interpolation=ENLARGEMENTS[args.interpolation]))
        corners.append((ox, oy))
    asked = [ask(None, predictor.tokenizer, predictor.format_config, predictor._questions, predictor.context)] * len(views)
    answers = predictor._decode(asked, views)
    unmoved = Framing(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), views[0].shape[0])
    zoomed = first.copy()
    for row, g in enumerate(mosaics):
        grasp = predictor._grasp(asked[row], unmoved, {p.question.part: answers[(row, p.question.part)]
                                                       for p in asked[row].prompts})
        zoomed[g] = [grasp.x / 2 + corners[row][0], grasp.y / 2 + corners[row][1], grasp.theta]
    hits_zoomed = tally.successes(evaluation.instructions, zoomed, "honest")
    multi = np.array(mosaics)
    single = np.setdiff1d(np.arange(len(evaluation.instructions)), multi)
    a, b = hits_first[multi], hits_zoomed[multi]
    by_kind = {}
    for g in mosaics:
        counts = by_kind.setdefault(evaluation.instructions[g].kind, [0, 0, 0])
        counts[0], counts[1], counts[2] = counts[0] + 1, counts[1] + int(hits_first[g]), counts[2] + int(hits_zoomed[g])
    figures = {"window": args.window, "interpolation": args.interpolation, "workdir": args.workdir, "step": step,
               "single": round(float(hits_first[single].mean() * 100), 4),
               "multi_one_pass": round(float(a.mean() * 100), 4), "multi_zoomed": round(float(b.mean() * 100), 4),
               "mosaic_instructions": len(multi), "right_only_zoomed": int((b & ~a).sum()),
               "right_only_one_pass": int((a & ~b).sum()), "by_kind": by_kind}
    figures["mcnemar_z"] = mcnemar_z(figures["right_only_zoomed"], figures["right_only_one_pass"])
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
