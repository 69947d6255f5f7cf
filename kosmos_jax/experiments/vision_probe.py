"""Can a run's vision tower, trained from scratch, find the grasp at all? A fresh tower of the run's
model config with a linear readout, trained on the run's training split to regress the target
grasp centre directly (L1 loss, AdamW), then scored on the test split against the constant guess of
the training answers' mean centre.

    python -m kosmos_jax.experiments.vision_probe --workdir=runs/demo [--steps=300] [--readout=patches] [--json]

The readout `patches` reads every patch feature (a position-aware linear map, the easiest case for
the tower), `cls` the class token alone. If the probe cannot beat the constant guess in a budget,
the language model on top of the same tower, trained for the same budget, has nothing to read. The
train error against the test error tells learning from memorising the training photos.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx

from kosmos_jax.evaluate.run import RunError, open_run
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.models.vision import VisionModel
from kosmos_jax.train import data as data_lib

READOUTS = ("patches", "cls")


class CentreProbe(nnx.Module):
    """Vision tower + linear map to the grasp centre, in units of the stored view's side."""

    def __init__(self, vision_config, readout: str, rngs: nnx.Rngs):
        self.readout, self.image_size = readout, vision_config.image_size
        self.vision = VisionModel(vision_config, jnp.float32, rngs)
        tokens = vision_config.num_positions if readout == "patches" else 1
        # Zero weights and a bias on the view's centre: a random readout of ~8k unit features would
        # start a view's side away from any answer, and the probe would spend its budget undoing that.
        self.head = nnx.Linear(tokens * vision_config.hidden_size, 2, kernel_init=nnx.initializers.zeros,
                               bias_init=nnx.initializers.constant(0.5), rngs=rngs)

    def __call__(self, images: jax.Array) -> jax.Array:
        features = self.vision(pixels(images, self.image_size))  # unit-norm tokens [B, 1 + patches, D]
        features = features if self.readout == "patches" else features[:, :1]
        return self.head(features.reshape(features.shape[0], -1) * np.sqrt(features.shape[-1]))


@nnx.jit
def train_step(probe, optimizer, images, centres):
    def loss(model):
        return jnp.mean(jnp.abs(model(images) - centres))

    value, grads = nnx.value_and_grad(loss)(probe)
    optimizer.update(probe, grads)
    return value


@nnx.jit
def predict(probe, images):
    return probe(images)


def vision_probe(workdir, steps: int = 300, readout: str = "patches", batch_size: int = 32, lr: float = 1e-4,
                 seed: int = 0, progress=None) -> dict:
    """{"steps", "readout", "train_examples_seen", "test_examples", "mae_px": [x, y], "mean_guess_mae_px": [x, y],
    "centres_px": {split: {"mean", "std"}}}: mean absolute error of the centre on the test split, in
    stored-view pixels, and the spread of the target centres the probe trained and was tested on."""
    if readout not in READOUTS:
        raise ValueError(f"readout {readout!r}: expected one of {READOUTS}")
    if steps < 1 or batch_size < 1:
        raise ValueError(f"steps={steps} and batch_size={batch_size} must be at least 1")
    run = open_run(workdir)
    probe = CentreProbe(run.model_config.vision, readout, nnx.Rngs(seed))
    optimizer = nnx.Optimizer(probe, optax.adamw(lr), wrt=nnx.Param)
    batches = data_lib.train_batches(run.split("train"), batch_size, seed, 0, 1)
    seen = []
    for step in range(1, steps + 1):
        batch = next(batches)
        side = batch["image"].shape[1]
        loss = train_step(probe, optimizer, jnp.asarray(batch["image"]), jnp.asarray(batch["grasp"][:, :2] / side))
        seen.append(batch["grasp"][:, :2])
        if progress and (step % 50 == 0 or step == steps):
            progress(f"step {step}/{steps}: train L1 {float(loss) * side:.1f} px")
    mean_guess = np.concatenate(seen).mean(0)
    errors, tested = [], []
    for batch in data_lib.eval_batches(run.split("test"), batch_size, 0, 1):
        keep = batch["example_index"] >= 0
        side = batch["image"].shape[1]
        predicted = np.asarray(predict(probe, jnp.asarray(batch["image"]))) * side
        errors.append(np.abs(predicted - batch["grasp"][:, :2])[keep])
        tested.append(batch["grasp"][keep, :2])
    errors, tested, seen = np.concatenate(errors), np.concatenate(tested), np.concatenate(seen)
    spread = lambda centres: {"mean": centres.mean(0).tolist(), "std": centres.std(0).tolist()}
    return {"steps": steps, "readout": readout, "batch_size": batch_size, "train_examples_seen": len(seen),
            "test_examples": len(errors), "mae_px": errors.mean(0).tolist(),
            "mean_guess_mae_px": np.abs(tested - mean_guess).mean(0).tolist(),
            "centres_px": {"train": spread(seen), "test": spread(tested)}}  # where the answers lie in the views


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m kosmos_jax.experiments.vision_probe",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--workdir", required=True, help="a KOSMOS-E run: its config, dataset and splits")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--readout", choices=READOUTS, default="patches")
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--lr", type=float, default=1e-4)
    parser.add_argument("--json", action="store_true", help="print the result as one JSON line")
    args = parser.parse_args(argv)
    started = time.time()
    try:
        result = vision_probe(args.workdir, args.steps, args.readout, args.batch_size, args.lr,
                              progress=lambda line: print(line, file=sys.stderr, flush=True))
    except (RunError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    result["wall_s"] = round(time.time() - started, 1)
    if args.json:
        print(json.dumps(result))
    else:
        mae, guess = result["mae_px"], result["mean_guess_mae_px"]
        print(f"{args.readout} readout, {args.steps} steps: test centre error x {mae[0]:.1f} px, y {mae[1]:.1f} px "
              f"(the training mean as a guess: x {guess[0]:.1f}, y {guess[1]:.1f}; {result['test_examples']} examples)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
