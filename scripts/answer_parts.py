"""Where a run's single-photo answers land on the object: which part, another part, or off it, a probe (issue 22).

    python scripts/answer_parts.py --workdir=RUN --scored=cornell-synthetic-300-seed7 [--step=N] [>> RECORDS.jsonl]

The part oracles say a single photo's miss is mostly its centre. This asks what kind of centre miss it is.
For every single-photo instruction of a synthetic folder that `evaluate --cornell` scored, the answered centre
is placed among the photo's parts (synthetic_meta.json's polygons, moved into the honest test view as the
evaluation moves the grasps):
  graspable_with_truth  on a graspable part that holds one of the folder's grasps (the annotation's own parts)
  graspable_no_truth    on a graspable part the folder's draw left without a grasp
  not_graspable         on a part no grasp is ever drawn on (a cap, a hammer's head, ...)
  off_object            on no part; its distance to the nearest part is reported
and each class is split into hits and misses (the rectangle metric, honest protocol). For the misses that land on
a part holding a grasp, the angle error to the nearest ground truth says whether the angle or the place lost them.
With --trained_from=N:F the scored folder holds the first photos of a set of N written with the same seed (the
generator plans photo i alike for any N), and the hits are also split by whether each photo was in the training
split of that set's honest image-wise fold F (5 folds, fold seed 0, as make demo builds it): whether the run fits
the photos it trained on better than others. Prints one JSON line.
"""

import argparse
import collections
import json
import sys

import numpy as np
import shapely

from kosmos_jax import geometry
from kosmos_jax.diagnostics.annotation_draws import view_matrix
from kosmos_jax.diagnostics.categories import synthetic_header
from kosmos_jax.diagnostics.part_oracles import answered_grasps, nearest_truths, scored_folder_answers
from kosmos_jax.scoring import tally
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.scoring.instructions import group_instructions, text
from kosmos_jax.sources import splits
from kosmos_jax.text.formatter import FormatConfig

CLASSES = ("graspable_with_truth", "graspable_no_truth", "not_graspable", "off_object")


def view_polygon(part: dict, matrix: np.ndarray) -> shapely.Polygon:
    """A part's polygon (photo pixels, with holes) moved into the view by the [2, 3] affine `matrix`."""
    move = lambda points: np.asarray(points, float) @ matrix[:, :2].T + matrix[:, 2]
    return shapely.Polygon(move(part["polygon"]), [move(hole) for hole in part["holes"]])


def place(centre: np.ndarray, photo: dict, matrix: np.ndarray) -> tuple[str, str | None, float]:
    """(class, part name or None, distance in view px to the nearest part: 0 on a part) of one answered centre."""
    point = shapely.Point(*centre)
    polygons = [(part, view_polygon(part, matrix)) for part in photo["parts"]]
    for part, polygon in polygons:
        if polygon.covers(point):
            if not part["graspable"]:
                return "not_graspable", part["name"], 0.0
            held = part["name"] in photo["grasp_parts"]
            return ("graspable_with_truth" if held else "graspable_no_truth"), part["name"], 0.0
    return "off_object", None, float(min(polygon.distance(point) for _, polygon in polygons))


def training_photos(photos: int, fold: int) -> set[str]:
    """The photo ids in the training split of fold `fold` of a synthetic set of `photos` (honest, image-wise)."""
    ids = [scenes.photo_stem(index)[1] for index in range(photos)]
    train, _ = splits.split(ids, fold, "image", "honest", object_ids=None, k=5, seed=splits.fold_seed("honest", 0))
    return set(train)


def answer_parts(records, rows, config: FormatConfig, protocol: str, photos: dict, trained: set[str] | None = None) -> dict:
    """The figures the module docstring lists, overall and by category (and by `trained`, when given)."""
    instructions = [i for i in group_instructions(records) if i.scene == "single"]
    grasps = answered_grasps(instructions, rows, config)
    hits = np.asarray(tally.successes(instructions, grasps, protocol))
    truths = nearest_truths(instructions, grasps)
    matrix = view_matrix()
    counts = collections.Counter()
    by_category = collections.defaultdict(collections.Counter)
    off_distances, angle_errors, in_training = [], [], []
    for instruction, grasp, hit, truth in zip(instructions, grasps, hits, truths):
        photo_id = text(records[min(instruction.examples.values())]["photo_ids"][0])
        photo = photos[photo_id]
        in_training.append(trained is not None and photo_id in trained)
        if not np.isfinite(grasp).all():
            where = "unparsed"
        else:
            where, _, distance = place(grasp[:2], photo, matrix)
            if where == "off_object":
                off_distances.append(distance)
            if where == "graspable_with_truth" and not hit:
                angle_errors.append(float(np.degrees(geometry.angle_difference(grasp[2], truth[4]))))
        key = f"{where}:{'hit' if hit else 'miss'}"
        counts[key] += 1
        by_category[photo["category"]][key] += 1
    angle_errors, in_training = np.asarray(angle_errors), np.asarray(in_training)
    by_training = {} if trained is None else {
        name: {"instructions": int(members.sum()), "hits": int(hits[members].sum())}
        for name, members in (("trained", in_training), ("not_trained", ~in_training))}
    return {**({"by_training": by_training} if by_training else {}),"instructions": len(instructions), "hits": int(hits.sum()), "counts": dict(sorted(counts.items())),
            "off_object_px": {"median": round(float(np.median(off_distances)), 2) if off_distances else None,
                              "within_5": int(np.sum(np.asarray(off_distances) <= 5))},
            "misses_on_truth_part": {"answers": int(len(angle_errors)),
                                     "angle_within_30_deg": int(np.sum(angle_errors <= 30))},
            "categories": {category: dict(sorted(count.items())) for category, count in sorted(by_category.items())}}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--scored", required=True, help="eval/STEP/SCORED of a synthetic folder evaluate --cornell scored")
    parser.add_argument("--step", type=int, default=None)
    parser.add_argument("--trained_from", default="", help="N:F, the module docstring")
    args = parser.parse_args(argv)
    run, step, records, protocol, folder, answers = scored_folder_answers(args, "parts are known for synthetic folders only")
    photos = synthetic_header(folder, "parts are known for folders written by python -m kosmos_jax.sources.synthetic")["photos"]
    trained = None
    if args.trained_from:
        count, fold = (int(part) for part in args.trained_from.split(":"))
        trained = training_photos(count, fold)
    figures = answer_parts(records, answers, run.format_config, protocol, photos, trained)
    print(json.dumps({"workdir": args.workdir, "step": step, "scored": args.scored, **figures}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
