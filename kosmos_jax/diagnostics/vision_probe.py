"""Can a run's vision tower, trained from scratch, find the grasp at all? A fresh tower of the run's
model config with a linear readout, trained on the run's training split to find the target grasp
centre directly (AdamW), then scored on the test split against the constant guess of
the training answers' mean centre.

    python -m kosmos_jax.diagnostics.vision_probe --workdir=runs/demo [--steps=300] [--readout=patches] [--json]

The readout `patches` regresses the centre from every patch feature (a position-aware linear map),
`cls` from the class token alone, and `cells` scores each patch with one shared linear map and
classifies which patch holds the centre (softmax cross-entropy; the answer is the centre of the
best patch), the way a decoder that points at one image token would read it. If the probe cannot
beat the constant guess in a budget, the language model on top of the same tower, trained for the
same budget, has nothing to read. The train error against the test error tells learning from
memorising the training photos.
"""

from __future__ import annotations

import json
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import optax
from absl import flags
from flax import nnx

from kosmos_jax import commands
from kosmos_jax.workdir.files import RunError
from kosmos_jax.workdir.run import open_run
from kosmos_jax.models.patch_grid import cell_centre, cell_index
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.models.vision import VisionModel
from kosmos_jax.train import batches as batches_lib

READOUTS = ("patches", "cls", "cells")


class CentreProbe(nnx.Module):
    """Vision tower + linear map to the grasp centre, in units of the stored view's side."""

    def __init__(self, vision_config, readout: str, rngs: nnx.Rngs):
        self.readout, self.image_size = readout, vision_config.image_size
        self.grid = vision_config.image_size // vision_config.patch_size
        self.vision = VisionModel(vision_config, jnp.float32, rngs)
        if readout == "cells":
            self.head = nnx.Linear(vision_config.hidden_size, 1, rngs=rngs)  # one score a patch
            return
        tokens = vision_config.num_positions if readout == "patches" else 1
        # Zero weights and a bias on the view's centre: a random readout of ~8k unit features would
        # start a view's side away from any answer, and the probe would spend its budget undoing that.
        self.head = nnx.Linear(tokens * vision_config.hidden_size, 2, kernel_init=nnx.initializers.zeros,
                               bias_init=nnx.initializers.constant(0.5), rngs=rngs)

    def outputs(self, images: jax.Array) -> jax.Array:
        """[B, 2] centres in units of the view's side, or [B, patches] cell scores for `cells`."""
        features = self.vision(pixels(images, self.image_size))  # unit-norm tokens [B, 1 + patches, D]
        scale = np.sqrt(features.shape[-1])
        if self.readout == "cells":
            return self.head(features[:, 1:] * scale)[..., 0]
        features = features if self.readout == "patches" else features[:, :1]
        return self.head(features.reshape(features.shape[0], -1) * scale)

    def loss(self, images: jax.Array, centres: jax.Array) -> jax.Array:
        outputs = self.outputs(images)
        if self.readout != "cells":
            return jnp.mean(jnp.abs(outputs - centres))  # L1
        return optax.softmax_cross_entropy_with_integer_labels(outputs, cell_index(centres, self.grid)).mean()

    def __call__(self, images: jax.Array) -> jax.Array:
        """[B, 2] predicted centres in units of the view's side."""
        outputs = self.outputs(images)
        if self.readout != "cells":
            return outputs
        return cell_centre(jnp.argmax(outputs, axis=-1), self.grid)


@nnx.jit
def train_step(probe, optimizer, images, centres):
    value, grads = nnx.value_and_grad(lambda model: model.loss(images, centres))(probe)
    optimizer.update(probe, grads)
    return value  # L1 in view units, or cross-entropy in nats for `cells`


@nnx.jit
def predict(probe, images):
    return probe(images)


def vision_probe(workdir, steps: int = 300, readout: str = "patches", batch_size: int = 32, lr: float = 1e-4,
                 seed: int = 0, progress=None) -> dict:
    """{"steps", "readout", "train_examples_seen", "test_examples", "mae_px": [x, y], "mean_guess_mae_px": [x, y],
    "within_20px", "mean_guess_within_20px", "centres_px": {split: {"mean", "std"}}}: mean absolute
    error of the centre on the test split, in stored-view pixels, the share of test centres within
    20 px, and the spread of the target centres the probe trained and was tested on."""
    if readout not in READOUTS:
        raise ValueError(f"readout {readout!r}: expected one of {READOUTS}")
    if steps < 1 or batch_size < 1:
        raise ValueError(f"steps={steps} and batch_size={batch_size} must be at least 1")
    run = open_run(workdir)
    probe = CentreProbe(run.model_config.vision, readout, nnx.Rngs(seed))
    optimizer = nnx.Optimizer(probe, optax.adamw(lr), wrt=nnx.Param)
    batches = batches_lib.train_batches(run.split("train"), batch_size, seed, 0, 1)
    seen = []
    for step in range(1, steps + 1):
        batch = next(batches)
        side = batch["image"].shape[1]
        loss = train_step(probe, optimizer, jnp.asarray(batch["image"]), jnp.asarray(batch["grasp"][:, :2] / side))
        seen.append(batch["grasp"][:, :2])
        if progress and (step % 50 == 0 or step == steps):
            shown = f"cross-entropy {float(loss):.3f}" if readout == "cells" else f"L1 {float(loss) * side:.1f} px"
            progress(f"step {step}/{steps}: train {shown}")
    mean_guess = np.concatenate(seen).mean(0)
    errors, tested = [], []
    for batch in batches_lib.eval_batches(run.split("test"), batch_size, 0, 1):
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
            # the share of test centres found within 20 px (about what the rectangle metric forgives)
            "within_20px": float(np.mean(np.hypot(*errors.T) < 20)),
            "mean_guess_within_20px": float(np.mean(np.hypot(*(tested - mean_guess).T) < 20)),
            "centres_px": {"train": spread(seen), "test": spread(tested)}}  # where the answers lie in the views


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("string", "workdir", None, "a KOSMOS-E run: its config, dataset and splits")
    define("integer", "steps", 300, "training steps of the probe")
    define("enum", "readout", "patches", "what the probe reads", enum_values=list(READOUTS))
    define("integer", "batch_size", 32, "examples a step")
    define("float", "lr", 1e-4, "the probe's learning rate")
    define("bool", "json", False, "print the result as one JSON line")
    flags.mark_flag_as_required("workdir", flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_flags, probe_command, argv, prog="python -m kosmos_jax.diagnostics.vision_probe",
                                doc=__doc__)


def probe_command(args) -> int:
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
              f"(the training mean as a guess: x {guess[0]:.1f}, y {guess[1]:.1f}; {result['test_examples']} examples); "
              f"within 20 px: {100 * result['within_20px']:.1f}% (the guess: {100 * result['mean_guess_within_20px']:.1f}%)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
