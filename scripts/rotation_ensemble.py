"""Single photos answered on the view and its quarter turns (and mirror images), combined: a probe.

    python scripts/rotation_ensemble.py --workdir=RUN --cornell=datasets/synthetic-300-seed7 \
        [--views=4] [>> RECORDS.jsonl]

Each photo's NON instruction is answered on the view turned by k quarter turns anticlockwise
(np.rot90, exact pixels; views 5 to 8 mirror it left to right first), each answer mapped back to the
view (a quarter turn moves (x, y) to (y, S - x) and adds pi/2 to the angle; the mirror moves x to
S - x and negates the angle). Then two ways of combining them: `consensus`, the answer that agrees
with most of the others (centres within 10 px, angles within 30 degrees; ties go to the unturned
view's), and `cluster_mean`, the mean of the answers agreeing with that one (the angle's mean of
exp(2i theta)). Prints one JSON line: each view's accuracy, both
combinations', and `any_view`, the share right in at least one view.
"""

import argparse
import json

import numpy as np

from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_decoding import chosen_windows, configured_windows
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.workdir.run import open_run


def unturned(grasps: np.ndarray, turns: int, mirrored: bool, size: int) -> np.ndarray:
    """[G, 3] answers on the turned (mirrored) view -> the view's own pixels and angles."""
    x, y, theta = grasps[:, 0], grasps[:, 1], grasps[:, 2]
    for _ in range(turns):
        x, y, theta = size - y, x, theta - np.pi / 2
    if mirrored:
        x, theta = size - x, -theta
    return np.stack([x, y, (theta + np.pi / 2) % np.pi - np.pi / 2], axis=1)


def agree(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    centres = np.hypot(a[..., 0] - b[..., 0], a[..., 1] - b[..., 1]) < 10
    return centres & (np.abs((a[..., 2] - b[..., 2] + np.pi / 2) % np.pi - np.pi / 2) < np.pi / 6)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--cornell", required=True)
    parser.add_argument("--views", type=int, choices=range(1, 9), default=4)
    args = parser.parse_args()
    run, mesh = open_run(args.workdir), make_mesh(1, -1, 1)
    _, params = run.params(None, mesh)
    records = cornell_examples(args.cornell, run.tokenizer, run.format_config, ("non",)).records
    windows = chosen_windows(configured_windows(run.config))
    size = records[0]["image"].shape[0]
    answers, instructions = [], None
    for view in range(args.views):
        turns, mirrored = view % 4, view >= 4
        shown = [{**r, "image": np.ascontiguousarray(np.rot90(r["image"][:, ::-1] if mirrored else r["image"], turns))}
                 for r in records]
        evaluation = GraspEvaluation(run.model_config, mesh, shown, run.tokenizer, run.format_config, "honest", **windows)
        answers.append(unturned(evaluation.grasps(evaluation.answers(params)), turns, mirrored, size))
        instructions = instructions or evaluation.instructions
    every = np.stack(answers)  # [V, G, 3]
    hits = [tally.successes(instructions, grasps, "honest") for grasps in every]
    votes = np.stack([sum(agree(every[i], every[j]) for j in range(args.views) if j != i) for i in range(args.views)])
    chosen = every[np.argmax(votes + 1e-3 * (np.arange(args.views) == 0)[:, None], axis=0), np.arange(every.shape[1])]
    weights = np.stack([agree(grasps, chosen) for grasps in every]).astype(float)
    mean = np.stack([(every[..., 0] * weights).sum(0) / weights.sum(0), (every[..., 1] * weights).sum(0) / weights.sum(0),
                     np.angle((weights * np.exp(2j * every[..., 2])).sum(0)) / 2], axis=1)
    percent = lambda found: round(float(np.mean(found) * 100), 4)
    figures = {"workdir": args.workdir, "views": args.views, "per_view": [percent(h) for h in hits],
               "consensus": percent(tally.successes(instructions, chosen, "honest")),
               "cluster_mean": percent(tally.successes(instructions, mean, "honest")),
               "any_view": percent(np.any(hits, axis=0)), "instructions": len(instructions)}
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
