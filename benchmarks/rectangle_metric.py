"""Rectangle IoU: our jit exact backend against shapely's vectorised intersection, same run.

    .venv/bin/python benchmarks/rectangle_metric.py [--pairs 100000] [--repeats 5]

Prints pairs/s of each, their ratio, the max IoU difference and the number of pairs whose
IoU > 0.25 decision differs; then times grasp_success on 10,000 images with up to 32 ground truths.
Shapely is timed on polygons built beforehand (its most favourable case); ours starts from
(x, y, w, h, theta) arrays already on the device.
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np
import shapely

from kosmos_jax import geometry
from kosmos_jax.metrics import grasp_success, rectangle_iou


def best_time(fn, repeats):
    fn()  # warm-up (compilation for jax)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


def random_pairs(rng, n):
    a = np.c_[rng.uniform(0, 224, (n, 2)), rng.uniform(5, 60, (n, 2)), rng.uniform(-np.pi / 2, np.pi / 2, n)]
    b = np.c_[a[:, :2] + rng.normal(0, 15, (n, 2)), rng.uniform(5, 60, (n, 2)), rng.uniform(-np.pi / 2, np.pi / 2, n)]
    return a, b


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", type=int, default=100_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--images", type=int, default=10_000)
    parser.add_argument("--max-gts", type=int, default=32)
    args = parser.parse_args()

    rng = np.random.default_rng(0)
    a, b = random_pairs(rng, args.pairs)
    a32, b32 = jax.device_put(a.astype(np.float32)), jax.device_put(b.astype(np.float32))
    ours = best_time(lambda: rectangle_iou(a32, b32).block_until_ready(), args.repeats)

    poly_a = shapely.polygons(geometry.grasps_to_corners(a))
    poly_b = shapely.polygons(geometry.grasps_to_corners(b))

    def shapely_iou():
        inter = shapely.area(shapely.intersection(poly_a, poly_b))
        union = shapely.area(poly_a) + shapely.area(poly_b) - inter
        return inter / union

    theirs = best_time(shapely_iou, max(1, args.repeats // 2))
    difference = np.abs(np.asarray(rectangle_iou(a32, b32), np.float64) - shapely_iou())
    decisions = int(np.sum((np.asarray(rectangle_iou(a32, b32)) > 0.25) != (shapely_iou() > 0.25)))
    with jax.enable_x64(True):
        diff64 = float(np.abs(np.asarray(rectangle_iou(a, b)) - shapely_iou()).max())

    counts = rng.integers(1, args.max_gts + 1, args.images)
    gt_mask = np.arange(args.max_gts)[None, :] < counts[:, None]
    centres = rng.uniform(40, 184, (args.images, 1, 2)) + rng.normal(0, 8, (args.images, args.max_gts, 2))
    gts = np.concatenate(
        [centres, rng.uniform(10, 50, (args.images, args.max_gts, 2)), rng.uniform(-1.5, 1.5, (args.images, args.max_gts, 1))],
        axis=-1,
    ).astype(np.float32)
    pred = np.c_[rng.uniform(40, 184, (args.images, 2)), rng.uniform(-1.5, 1.5, args.images)].astype(np.float32)
    pred, gts, gt_mask = jax.device_put(pred), jax.device_put(gts), jax.device_put(gt_mask)
    timings = {}
    for backend in ("exact", "reference"):
        for policy in ("per_gt", "kosmos_e"):
            seconds = best_time(
                lambda: grasp_success(pred, gts, gt_mask, backend=backend, wh_policy=policy, max_rows=256).block_until_ready(),
                args.repeats,
            )
            timings[f"{backend}/{policy}"] = round(args.images / seconds)

    report = {
        "pairs": args.pairs,
        "ours_exact_jit_pairs_per_s": round(args.pairs / ours),
        "shapely_pairs_per_s": round(args.pairs / theirs),
        "ratio_ours_over_shapely": round(theirs / ours, 2),
        "max_abs_iou_difference_float32": float(difference.max()),
        "max_abs_iou_difference_float64": diff64,
        "differing_decisions_at_0.25": decisions,
        "grasp_success_images_per_s": timings,
        "grasp_success_setup": f"{args.images} images, 1..{args.max_gts} ground truths each",
        "devices": str(jax.devices()),
    }
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
