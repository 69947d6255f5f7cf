"""Would answers averaged over views shifted by half a patch place the centre better? A probe.

    python scripts/shifted_views.py --workdir=demo_out/run --cornell=datasets/synthetic-300-seed7 \
        [--kinds=non] [--shifts=0:0,14:0,0:14,14:14]

Each shift (dx:dy, view pixels) moves every test view by that much (the edge pixels repeated into the
gap), the run answers it with its configured decoding, and the answers are moved back by -dx, -dy.
Prints one JSON line: each shift's accuracy, and the accuracy of the first k shifts combined (centre
by mean and by median, angle by the circular mean of 2 theta), overall and per scene. The demo's
patches are 28 px of its 224 px view, so a centre tied to the patch grid would move between shifts of
14 px and average to a finer one.
"""

import argparse
import json

import cv2
import numpy as np

from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_decoding import chosen_windows, configured_windows
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.workdir.run import open_run


def shifted(image: np.ndarray, dx: int, dy: int) -> np.ndarray:
    moved = np.float32([[1, 0, dx], [0, 1, dy]])
    return cv2.warpAffine(image, moved, image.shape[1::-1], flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)


class ShiftedRecords:
    """The records with every image moved by (dx, dy), each moved once (the evaluation reads them often)."""

    def __init__(self, records, dx: int, dy: int):
        self.records = records
        self.images = [shifted(np.asarray(record["image"]), dx, dy) for record in records]

    def __len__(self):
        return len(self.records)

    def __getitem__(self, index):
        return {**self.records[index], "image": self.images[index]}


def combined(grasps: np.ndarray, centre: str) -> np.ndarray:
    """[K, G, 3] answers of K shifts (moved back) -> [G, 3]."""
    xy = getattr(np, centre)(grasps[..., :2], axis=0)
    theta = np.angle(np.exp(2j * grasps[..., 2]).mean(0)) / 2
    return np.concatenate([xy, theta[:, None]], -1)


def figures(instructions, hits: np.ndarray) -> dict:
    out = {"all": tally.percent(hits)}
    for scene, members in tally.group_members(instructions, lambda i: i.scene).items():
        out[scene] = tally.percent(hits[members])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--cornell", required=True)
    parser.add_argument("--kinds", default="non")
    parser.add_argument("--shifts", default="0:0,14:0,0:14,14:14")
    args = parser.parse_args()
    shifts = [tuple(int(v) for v in s.split(":")) for s in args.shifts.split(",")]
    run = open_run(args.workdir)
    mesh = make_mesh(1, -1, 1)
    step, params = run.params(None, mesh)
    records = cornell_examples(args.cornell, run.tokenizer, run.format_config, tuple(args.kinds.split(","))).records
    windows = chosen_windows(configured_windows(run.config))
    first, answered, report = None, [], {"workdir": args.workdir, "step": step, "cornell": args.cornell,
                                          "kinds": args.kinds, "windows": windows, "shifts": {}}
    for dx, dy in shifts:
        evaluation = GraspEvaluation(run.model_config, mesh, ShiftedRecords(records, dx, dy), run.tokenizer,
                                     run.format_config, "honest", **windows)
        if first is None:
            first = evaluation
        else:
            evaluation.decoder = first.decoder  # one decoder: its compiled programs serve every shift
        grasps = evaluation.grasps(evaluation.answers(params)) - np.array([dx, dy, 0.0])
        answered.append(grasps)
        report["shifts"][f"{dx}:{dy}"] = figures(first.instructions, tally.successes(first.instructions, grasps, "honest"))
    stack = np.stack(answered)
    report["combined"] = {f"{centre} of {k}": figures(first.instructions, tally.successes(
        first.instructions, combined(stack[:k], centre), "honest")) for k in range(2, len(shifts) + 1)
        for centre in ("mean", "median")}
    print(json.dumps(report))


if __name__ == "__main__":
    main()
