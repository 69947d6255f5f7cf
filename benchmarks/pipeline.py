"""INSTRUCT-GRASP build time and input-pipeline throughput, with the consumer in the same run.

    .venv/bin/python benchmarks/pipeline.py [--source DIR] [--augmentations 16] [--batches 40]

1. Builds a dataset from a Cornell-format folder (default: ../shared/data/cornell with the
   KOSMOS-E annotations, else 40 synthetic photos) at the paper's density (16 augmentations per
   training photo as 4 whole-degree rotations x 4 shifts, every instruction kind), honest protocol,
   object-wise fold 0, and times it; reports the examples and distinct images stored per split
   (each image once, examples refer to it) and the bytes on disk.
2. Reads the training split with the grain pipeline (shuffle, join each example's image, decode,
   fixed-shape batches of 32) and reports samples/s; the peer is a plain Python loop reading the
   same records (image joined) in the same shuffled order and stacking them, in the same run.
3. The consumer: samples/s of one forward+backward pass of the `small` model on batches of the same
   shape, so "far above what a training step consumes" is a printed ratio, not a claim.
The built dataset lives in a temporary folder removed at the end (--keep to keep it).
"""

from __future__ import annotations

import argparse
import json
import pathlib
import shutil
import sys
import tempfile
import time

import numpy as np

from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.dataset import build
from kosmos_jax.dataset import pipeline, tfds_builders

REPO = pathlib.Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared" / "data"


def source_and_annotations(args, scratch: pathlib.Path):
    if args.source:
        return pathlib.Path(args.source), args.annotations
    if (SHARED / "cornell").exists():
        annotations = SHARED / "kosmos-e" / "instructions-original.json"
        return SHARED / "cornell", str(annotations) if annotations.exists() else None
    root = scratch / "synthetic"
    scenes.write_dataset(root, photos=40, seed=0)
    return root, None


def time_grain(source, batch_size: int, batches: int) -> float:
    iterator = iter(pipeline.make_dataset(source, batch_size, seed=0, num_epochs=None))
    next(iterator)  # start-up: threads, first reads
    start = time.perf_counter()
    for _ in range(batches):
        next(iterator)
    return batches * batch_size / (time.perf_counter() - start)


def time_plain_loop(source, batch_size: int, batches: int) -> float:
    order = np.random.default_rng(0).permutation(len(source))
    start = time.perf_counter()
    for b in range(batches):
        rows = [pipeline.to_arrays(source[int(i)], 64) for i in order[np.arange(b * batch_size, (b + 1) * batch_size) % len(order)]]
        {name: np.stack([row[name] for row in rows]) for name in rows[0]}
    return batches * batch_size / (time.perf_counter() - start)


def time_small_model_step(batch_size: int, length: int) -> float:
    """Samples/s of forward+backward of the `small` model on batches of this shape."""
    sys.path.insert(0, str(pathlib.Path(__file__).parent))
    from model import train_step_speed  # benchmarks/model.py: the same timed step

    from kosmos_jax.models import config as config_lib

    step = train_step_speed(config_lib.get_config("small"), batch_size, length)
    return batch_size / step["step_seconds"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source")
    parser.add_argument("--annotations")
    parser.add_argument("--augmentations", type=int, default=16)
    parser.add_argument("--batch", type=int, default=32)
    parser.add_argument("--batches", type=int, default=40)
    parser.add_argument("--keep", action="store_true")
    args = parser.parse_args()

    scratch = pathlib.Path(tempfile.mkdtemp(prefix="kosmos_bench_"))
    try:
        source, annotations = source_and_annotations(args, scratch)
        config = build.BuildConfig(source=str(source), out=str(scratch / "built"), protocol="honest", split="object",
                                   fold=0, augmentations=args.augmentations, recipe="paper", annotations=annotations)
        start = time.perf_counter()
        stats = build.build(config)
        build_seconds = time.perf_counter() - start
        train = tfds_builders.open_splits(stats["dataset_dir"])["train"]
        length = int(np.asarray(train[0]["tokens"]).shape[0])
        grain_rate = time_grain(train, args.batch, args.batches)
        plain_rate = time_plain_loop(train, args.batch, args.batches)
        step_rate = time_small_model_step(args.batch, length)
        splits = stats["splits"]
        report = {
            "source": str(source),
            "augmentations_per_training_photo": args.augmentations,
            "build_seconds": round(build_seconds, 1),
            "reused": stats["reused"],
            "examples": {split: info["examples"] for split, info in splits.items()},
            "distinct_images": {split: info["images"] for split, info in splits.items()},
            "bytes_on_disk_by_split": {split: info["bytes_on_disk"] for split, info in splits.items()},
            "dataset_bytes": stats["bytes_on_disk"],  # every file but build_stats.json
            "grain_samples_per_s": round(grain_rate),
            "plain_loop_samples_per_s": round(plain_rate),
            "ratio_grain_over_plain_loop": round(grain_rate / plain_rate, 2),
            "small_model_fwd_bwd_samples_per_s": round(step_rate, 1),
            "ratio_pipeline_over_training_step": round(grain_rate / step_rate, 1),
            "batch": args.batch,
            "tokens_per_example": length,
        }
        print(json.dumps(report, indent=2))
        if args.keep:
            print(f"kept {scratch}")
    finally:
        if not args.keep:
            shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
