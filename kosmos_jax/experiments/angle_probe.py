"""Does a run's vision tower carry the grasp's angle at the grasp's patch? A ridge readout of
(cos 2theta, sin 2theta) from the tower's feature at the patch that holds the target grasp's centre,
fit on the run's training views and scored on its test views (the share of answers within 30 degrees
of the target's angle), beside the same readout of the untrained tower the run started from (its
seed) and the constant answer of the training views' mean orientation.

    python -m kosmos_jax.experiments.angle_probe --workdir=runs/demo [--step=N] [--examples=3000] [--json]

If the trained tower reads no better than the untrained one, the language model's loss did not teach
the tower orientation, and no decoder on top of it can answer the angle from the photo.
"""

from __future__ import annotations

import argparse
import json
import sys

import jax.numpy as jnp
import numpy as np
from flax import nnx

from kosmos_jax import geometry
from kosmos_jax.models.connector import cell_index
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.workdir.files import RunError
from kosmos_jax.workdir.run import open_run

WITHIN_DEG = 30.0


@nnx.jit
def _grasp_cell_features(vision, images, centres):
    """[B, D] the tower's feature at the patch holding each centre (centres in units of the view's side)."""
    features = vision(pixels(images, vision.model.embeddings.image_size))
    side = int(round((features.shape[1] - 1) ** 0.5))
    cell = 1 + cell_index(centres, side)
    return jnp.take_along_axis(features, cell[:, None, None], axis=1)[:, 0]


def one_per_view(split, count: int | None, seed: int) -> list[int]:
    """Indices of examples with a target angle, one per stored view, `count` of them drawn with `seed`."""
    seen, chosen = set(), []
    for index in np.random.default_rng(seed).permutation(len(split)):
        record = split.examples[int(index)]
        if record["image_index"] in seen or not np.isfinite(np.asarray(record["grasp"], np.float32)).all():
            continue
        seen.add(record["image_index"])
        chosen.append(int(index))
        if count is not None and len(chosen) == count:
            break
    return chosen


def features_and_angles(vision, split, indices, batch_size: int = 64) -> tuple[np.ndarray, np.ndarray]:
    features, angles = [], []
    for start in range(0, len(indices), batch_size):
        records = [split[i] for i in indices[start:start + batch_size]]
        images = np.stack([r["image"] for r in records])
        grasps = np.stack([np.asarray(r["grasp"], np.float32) for r in records])
        centres = jnp.asarray(grasps[:, :2] / images.shape[1])
        features.append(np.asarray(_grasp_cell_features(vision, jnp.asarray(images), centres)))
        angles.append(grasps[:, 4])
    return np.concatenate(features).astype(np.float64), np.concatenate(angles).astype(np.float64)


def doubled(angles: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(2 * angles), np.sin(2 * angles)], axis=1)


def within(read: np.ndarray, angles: np.ndarray) -> float:
    """Share (percent) of readouts [N, 2] whose angle lies within WITHIN_DEG of `angles`."""
    answered = np.arctan2(read[:, 1], read[:, 0]) / 2
    errors = np.degrees(np.asarray(geometry.angle_difference(answered, angles)))
    return round(float((errors <= WITHIN_DEG).mean() * 100), 2)


def ridge_readout(train_x, train_angles, ridge: float):
    """A linear map from standardised features (+ bias) to (cos 2theta, sin 2theta), fit in closed form."""
    mean, scale = train_x.mean(0), train_x.std(0) + 1e-6
    design = lambda x: np.c_[(x - mean) / scale, np.ones(len(x))]
    a = design(train_x)
    weights = np.linalg.solve(a.T @ a + ridge * len(a) * np.eye(a.shape[1]), a.T @ doubled(train_angles))
    return lambda x: design(x) @ weights


def angle_probe(workdir, step: int | None = None, examples: int = 3000, ridge: float = 0.01, seed: int = 0) -> dict:
    run = open_run(workdir)
    step, params = run.params(step)
    untrained = build(run.model_config, run.config.train.seed)
    graphdef, _, rest = split_model(untrained)
    trained = nnx.merge(graphdef, params, rest)
    train_split, test_split = run.split("train"), run.split("test")
    train_indices, test_indices = one_per_view(train_split, examples, seed), one_per_view(test_split, None, seed)
    result = {"step": step, "train_views": len(train_indices), "test_views": len(test_indices), "ridge": ridge}
    for name, model in (("trained", trained), ("untrained", untrained)):
        train_x, train_angles = features_and_angles(model.vision_model, train_split, train_indices)
        test_x, test_angles = features_and_angles(model.vision_model, test_split, test_indices)
        read = ridge_readout(train_x, train_angles, ridge)
        result[name] = {"train": within(read(train_x), train_angles), "test": within(read(test_x), test_angles)}
    mean_direction = doubled(train_angles).mean(0, keepdims=True)
    result["constant"] = {"test": within(np.repeat(mean_direction, len(test_angles), 0), test_angles)}
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m kosmos_jax.experiments.angle_probe", description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", required=True, help="a KOSMOS-E training run's folder")
    parser.add_argument("--step", type=int, default=None, help="checkpoint step (default: the newest)")
    parser.add_argument("--examples", type=int, default=3000, help="training views the readout is fit on")
    parser.add_argument("--ridge", type=float, default=0.01, help="ridge penalty per example, on standardised features")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON line")
    args = parser.parse_args(argv)
    if args.examples < 2:
        parser.error("--examples must be at least 2")
    try:
        result = angle_probe(args.workdir, args.step, args.examples, args.ridge)
    except RunError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(result))
        return 0
    print(f"step {result['step']}: share of test views within {WITHIN_DEG:.0f} degrees, read from the grasp's patch "
          f"({result['train_views']} training views, {result['test_views']} test views)")
    for name in ("trained", "untrained"):
        print(f"  {name} tower: test {result[name]['test']}%, train {result[name]['train']}%")
    print(f"  constant mean orientation: test {result['constant']['test']}%")
    return 0


if __name__ == "__main__":
    sys.exit(main())
