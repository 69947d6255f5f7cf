"""Augmentation throughput: our jit path against an OpenCV warpAffine loop, same work, same run.

    .venv/bin/python benchmarks/augment.py [--batch 64] [--per-photo 1] [--repeats 5]

Both sides take a batch of 480 x 640 x 3 uint8 photos with padded grasps, draw the recipe's
matrices (crop 351 -> rotate -> translate +-40 -> crop 224), warp each photo ONCE to 224 x 224
with bilinear sampling and a reflected border, and move and drop the grasps. OpenCV gets our
matrices converted to its pixel-index convention, so both do identical geometry; its loop runs
per photo with cv2's own threads (cv2.getNumThreads() printed). JAX is timed after compilation
on arrays already on the device, blocking on the result. Prints images/s of each and the ratio,
for synthetic photos and, when ../shared/data/cornell exists, for the real Cornell photos.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import cv2
import jax
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.augment import AugmentConfig, augment, pad_grasps, to_pixel_index_matrix

CORNELL = pathlib.Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cornell"


def best_time(fn, repeats):
    fn()  # warm-up (compilation for jax)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return min(times)


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
    return images, *pad_grasps(lists, max_grasps=16)


def cornell_batch(batch):
    from kosmos_jax.data.cornell import load_photos

    photos = load_photos(CORNELL)
    photos = [p for p in photos if p.rgb.shape == (480, 640, 3) and len(p.grasps)]
    photos = (photos * (batch // len(photos) + 1))[:batch]
    images = np.stack([p.rgb for p in photos])
    grasps, mask = pad_grasps([p.grasps for p in photos], max_grasps=max(len(p.grasps) for p in photos))
    return images, grasps, mask, len({p.id for p in photos})


def measure(images, grasps, mask, config, repeats):
    keys = jax.random.split(jax.random.key(0), images.shape[0])
    dev = [jax.device_put(a) for a in (images, grasps, mask)]

    def ours():
        return jax.block_until_ready(augment(*dev, keys, config))

    jit_s = best_time(ours, repeats)
    result = ours()
    matrices = np.asarray(result.matrices)
    cv_s = best_time(lambda: opencv_augment(images, grasps, mask, matrices, config.output_size), repeats)
    cv_images, cv_grasps, cv_mask = opencv_augment(images, grasps, mask, matrices, config.output_size)
    pixel_diff = np.abs(np.asarray(result.images, np.int32) - cv_images)
    samples = matrices.shape[0]
    return {
        "samples": samples,
        "jit_images_per_s": round(samples / jit_s, 1),
        "opencv_images_per_s": round(samples / cv_s, 1),
        "opencv_over_jit_time_ratio": round(jit_s / cv_s, 2),
        "max_pixel_difference": int(pixel_diff.max()),
        "mean_pixel_difference": round(float(pixel_diff.mean()), 4),
        "mask_disagreements": int(np.sum(np.asarray(result.mask) != cv_mask)),
        "dropped_grasps": int(np.asarray(result.dropped).sum()),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--per-photo", type=int, default=1, help="augmentations per photo")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    config = AugmentConfig(rotations_per_photo=args.per_photo)
    report = {
        "device": str(jax.devices()[0]),
        "cv2_threads": cv2.getNumThreads(),
        "batch_photos": args.batch,
        "augmentations_per_photo": args.per_photo,
    }
    rng = np.random.default_rng(0)
    report["synthetic_480x640"] = measure(*synthetic_batch(rng, args.batch), config, args.repeats)
    if CORNELL.exists():
        images, grasps, mask, distinct = cornell_batch(args.batch)
        report["cornell"] = {"distinct_photos": distinct, **measure(images, grasps, mask, config, args.repeats)}
    else:
        report["cornell"] = f"skipped: {CORNELL} not found"
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
