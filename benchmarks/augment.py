"""Augmentation throughput: our jit path against an OpenCV warpAffine loop, same work, same run.

    .venv/bin/python benchmarks/augment.py [--batch 64] [--per-photo 1] [--repeats 11] [--devices 1]

Both sides take a batch of 480 x 640 x 3 uint8 photos with padded grasps, warp each photo ONCE
to 224 x 224 by the recipe's matrix (crop 351 -> rotate -> translate +-40 -> crop 224) with
bilinear sampling and a reflected border, and move and drop the grasps. OpenCV gets our matrices
converted to its pixel-index convention, so both do identical geometry (the pixel difference is
printed); its loop runs per photo with cv2's own thread pool (cv2.getNumThreads() printed).

XLA's CPU runtime already spreads the warp over both cores of this machine (its wall time is
about half its CPU time when the machine is quiet); --devices N > 1 adds a run with the batch
split by jax.shard_map over N CPU devices (XLA_FLAGS --xla_force_host_platform_device_count, set
here before jax starts) for comparison. JAX is timed after compilation on arrays already on the device,
blocking on the result. The contestants take turns for --repeats rounds (this machine is shared,
so its load varies); the median and best wall times are reported as images/s and as the ratio
jit time / OpenCV time (goal: <= 2), with the process CPU time per image of each (the work done,
whatever the load). Synthetic photos, and the real Cornell photos when ../shared/data/cornell
exists (the 101 photos there, repeated to fill the batch).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import time


def parse_args():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--per-photo", type=int, default=1, help="augmentations per photo")
    parser.add_argument("--repeats", type=int, default=11)
    parser.add_argument("--devices", type=int, default=1, help="CPU devices for an extra shard_map run (1: none)")
    return parser.parse_args()


ARGS = parse_args() if __name__ == "__main__" else None
if ARGS is not None and ARGS.devices > 1 and "xla_force_host_platform_device_count" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={ARGS.devices}").strip()

import cv2  # noqa: E402
import jax  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import NamedSharding, PartitionSpec  # noqa: E402

from kosmos_jax import geometry  # noqa: E402
from kosmos_jax.augment import AugmentConfig, augment, pad_grasps, to_pixel_index_matrix  # noqa: E402

CORNELL = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cornell"


def interleaved_times(fns, repeats):
    """(wall seconds, process CPU seconds) of each function over `repeats` rounds, the functions
    taking turns in each round so that a change in the machine's load hits all of them alike."""
    for fn in fns.values():
        fn()  # warm-up (compilation for jax)
    wall = {name: [] for name in fns}
    cpu = {name: 0.0 for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            before, start = os.times(), time.perf_counter()
            fn()
            wall[name].append(time.perf_counter() - start)
            after = os.times()
            cpu[name] += (after.user - before.user) + (after.system - before.system)
    return wall, cpu


def opencv_augment(images, grasps, mask, matrices, size):
    """The same work with OpenCV: one warpAffine per sample, grasps moved in numpy."""
    per_photo = matrices.shape[0] // images.shape[0]
    out = np.empty((matrices.shape[0], size, size, images.shape[-1]), np.uint8)
    index_matrices = to_pixel_index_matrix(matrices.astype(np.float64))
    for row in range(matrices.shape[0]):
        cv2.warpAffine(images[row // per_photo], index_matrices[row], (size, size), dst=out[row],
                       flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    repeated = np.repeat(grasps, per_photo, axis=0)
    moved = geometry.transform_grasps(repeated, matrices.astype(np.float64))
    inside = np.all((moved[..., :2] >= 0) & (moved[..., :2] < size), axis=-1)
    kept = np.repeat(mask, per_photo, axis=0) & inside
    return out, np.where(kept[..., None], moved, 0.0), kept


def synthetic_batch(rng, batch):
    images = rng.integers(0, 256, (batch, 480, 640, 3), dtype=np.uint8)
    images = cv2.GaussianBlur(images.reshape(batch * 480, 640, 3), (0, 0), 3).reshape(images.shape)
    lists = []
    for _ in range(batch):
        n = int(rng.integers(1, 12))
        centres = rng.normal((320, 240), 40, (n, 2))
        lists.append(np.c_[centres, rng.uniform(20, 60, (n, 2)), rng.uniform(-1.5, 1.5, n)])
    return (images, *pad_grasps(lists, max_grasps=16)), batch


def cornell_batch(batch):
    from kosmos_jax.sources.cornell import load_photos

    photos = [p for p in load_photos(CORNELL) if p.rgb.shape == (480, 640, 3) and len(p.grasps)]
    chosen = (photos * (batch // len(photos) + 1))[:batch]
    images = np.stack([p.rgb for p in chosen])
    grasps, mask = pad_grasps([p.grasps for p in chosen], max_grasps=max(len(p.grasps) for p in chosen))
    return (images, grasps, mask), len({p.id for p in chosen})


def measure(arrays, config, repeats, devices):
    images, grasps, mask = arrays
    keys = jax.random.split(jax.random.key(0), images.shape[0])
    on_one = [jax.device_put(a, jax.devices()[0]) for a in (images, grasps, mask, keys)]
    fns = {"jit_1_device": lambda: jax.block_until_ready(augment(*on_one, config))}
    result = fns["jit_1_device"]()
    if devices > 1:
        mesh = jax.make_mesh((devices,), ("batch",), axis_types=(jax.sharding.AxisType.Auto,))
        spec = PartitionSpec("batch")
        split = [jax.device_put(a, NamedSharding(mesh, spec)) for a in (images, grasps, mask, keys)]
        sharded = jax.jit(jax.shard_map(lambda *a: tuple(augment(*a, config)), mesh=mesh,
                                        in_specs=spec, out_specs=spec))
        fns[f"jit_{devices}_devices"] = lambda: jax.block_until_ready(sharded(*split))
        same = np.array_equal(np.asarray(fns[f"jit_{devices}_devices"]()[0]), np.asarray(result.images))
        assert same, "the shard_map run must give the same images"
    matrices = np.asarray(result.matrices)
    fns["opencv"] = lambda: opencv_augment(images, grasps, mask, matrices, config.output_size)
    wall, cpu = interleaved_times(fns, repeats)
    cv_images, _, cv_mask = opencv_augment(images, grasps, mask, matrices, config.output_size)
    pixel_diff = np.abs(np.asarray(result.images, np.int32) - cv_images)
    samples = matrices.shape[0]
    report = {"samples": samples}
    for name in fns:
        median, best = float(np.median(wall[name])), min(wall[name])
        report[name] = {
            "images_per_s_median": round(samples / median, 1),
            "images_per_s_best": round(samples / best, 1),
            "cpu_ms_per_image": round(cpu[name] / repeats / samples * 1e3, 3),
        }
        if name != "opencv":
            report[name]["time_over_opencv_median"] = round(median / float(np.median(wall["opencv"])), 2)
            report[name]["time_over_opencv_best"] = round(best / min(wall["opencv"]), 2)
    report.update({
        "max_pixel_difference_vs_opencv": int(pixel_diff.max()),
        "mean_pixel_difference_vs_opencv": round(float(pixel_diff.mean()), 4),
        "mask_disagreements_vs_opencv": int(np.sum(np.asarray(result.mask) != cv_mask)),
        "dropped_grasps": int(np.asarray(result.dropped).sum()),
    })
    return report


def main(args):
    config = AugmentConfig(rotations_per_photo=args.per_photo)
    devices = min(args.devices, len(jax.devices()))
    if args.batch % max(devices, 1):
        raise SystemExit(f"--batch {args.batch} must divide among {devices} devices")
    report = {
        "device": str(jax.devices()[0]),
        "cpus": os.cpu_count(),
        "cv2_threads": cv2.getNumThreads(),
        "batch_photos": args.batch,
        "augmentations_per_photo": args.per_photo,
        "load_average_at_start": [round(v, 2) for v in os.getloadavg()],
    }
    arrays, _ = synthetic_batch(np.random.default_rng(0), args.batch)
    report["synthetic_480x640"] = measure(arrays, config, args.repeats, devices)
    if CORNELL.exists():
        arrays, distinct = cornell_batch(args.batch)
        report["cornell"] = {"distinct_photos": distinct, **measure(arrays, config, args.repeats, devices)}
    else:
        report["cornell"] = f"skipped: {CORNELL} not found"
    report["load_average_at_end"] = [round(v, 2) for v in os.getloadavg()]
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main(ARGS)
