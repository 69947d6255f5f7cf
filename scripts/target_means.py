"""What a model that answers the mean of its targets would score, for each target rule, a probe (issues 21 and 22).

    python scripts/target_means.py --cornell=datasets/synthetic-300-seed7 [--draws=60] [--every=1] [>> RECORDS.jsonl]

A synthetic photo's grasps are a draw (sources/synthetic/scenes.draw_positives), so the fine-tune's target for one
photo changes from draw to draw. For each photo of a folder the generator wrote, and each target rule of
text/target_rows.py (random, top, consensus), DRAWS fresh draws are moved into the honest test view; each gives
the rule's target, and a second set of DRAWS draws scores:
  fitted  the targets themselves (the mean hit rate of one target against the other draws): a model that
          answers a sample of its target's distribution
  mean    one answer, the targets' mean centre and their mean angle (modulo pi): a model that answers the
          conditional mean of its targets
and `spread` is the median distance (view px) of a photo's target centres from their mean. By category and
overall; prints one JSON line.
"""

import argparse
import collections
import json
import sys

import numpy as np

from kosmos_jax.diagnostics.annotation_draws import in_view, view_matrix
from kosmos_jax.sources.synthetic.best_grasps import hit_rates
from kosmos_jax.diagnostics.categories import synthetic_header
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.text.target_rows import consensus_row, top_row

RULES = {"random": lambda grasps, rng: int(rng.integers(len(grasps))), "top": lambda grasps, rng: top_row(grasps),
         "consensus": lambda grasps, rng: consensus_row(grasps)}


def angle_mean(angles: np.ndarray) -> float:
    """The mean of grasp angles, which repeat every pi."""
    return 0.5 * float(np.angle(np.mean(np.exp(2j * angles))))


def photo_draws(seed: int, index: int, draws: int, matrix: np.ndarray) -> tuple[tuple, tuple] | None:
    """Two sets (grasps [D, M, 5], mask [D, M]) of fresh draws of one photo in the view, None if too few keep a grasp."""
    _, posed = scenes.posed_photo(seed, index)
    rng = np.random.default_rng([seed, index, 1])
    grasps, mask = in_view([scenes.draw_positives(rng, posed)[0] for _ in range(3 * draws)], matrix)
    kept = mask.any(axis=1)
    grasps, mask = grasps[kept], mask[kept]
    if len(grasps) < 2 * draws:
        return None
    return (grasps[:draws], mask[:draws]), (grasps[draws:2 * draws], mask[draws:2 * draws])


def rule_scores(targets_from: tuple, scored_by: tuple, rule, rng) -> tuple[float, float, float]:
    """(fitted, mean, spread) of one rule on one photo."""
    targets = np.stack([grasps[mask][rule(grasps[mask], rng)] for grasps, mask in zip(*targets_from)])
    fitted = float(hit_rates(targets[:, [0, 1, 4]], *scored_by).mean())
    centre = targets[:, :2].mean(axis=0)
    mean = np.array([[centre[0], centre[1], angle_mean(targets[:, 4])]], np.float32)
    spread = float(np.median(np.hypot(*(targets[:, :2] - centre).T)))
    return fitted, float(hit_rates(mean, *scored_by)[0]), spread


def target_means(folder, draws: int = 60, every: int = 1, progress: bool = False) -> dict:
    header = synthetic_header(folder, "only folders written by python -m kosmos_jax.sources.synthetic can be drawn again")
    matrix = view_matrix()
    scores = collections.defaultdict(lambda: collections.defaultdict(list))
    photos = sorted(header["photos"])[::every]
    for number, photo in enumerate(photos, start=1):
        index = int(photo.removeprefix("pcd")) - scenes.FIRST_NUMBER
        sets = photo_draws(header["seed"], index, draws, matrix)
        if sets is not None:
            rng = np.random.default_rng([header["seed"], index, 2])
            for name, rule in RULES.items():
                scores[header["photos"][photo]["category"]][name].append(rule_scores(*sets, rule, rng))
        if progress and (number % 25 == 0 or number == len(photos)):
            print(f"target means: {number}/{len(photos)} photos", file=sys.stderr, flush=True)

    def summary(rows):
        rows = np.asarray(rows)
        return {"photos": len(rows), "fitted": round(100 * float(rows[:, 0].mean()), 2),
                "mean": round(100 * float(rows[:, 1].mean()), 2), "spread_px": round(float(np.median(rows[:, 2])), 2)}
    every_photo = {name: [row for category in scores.values() for row in category[name]] for name in RULES}
    return {"folder": str(folder), "draws": draws, "every": every,
            "rules": {name: summary(rows) for name, rows in every_photo.items()},
            "categories": {category: {name: summary(rows) for name, rows in by_rule.items()}
                           for category, by_rule in sorted(scores.items())}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cornell", required=True, help="a folder written by python -m kosmos_jax.sources.synthetic")
    parser.add_argument("--draws", type=int, default=60)
    parser.add_argument("--every", type=int, default=1, help="score every N-th photo only")
    args = parser.parse_args(argv)
    print(json.dumps(target_means(args.cornell, args.draws, args.every, progress=True)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
