"""Does a trained KOSMOS-E read its image? The loss on the answer tokens of a split three ways: each
example with its own image, with another photo's image (the next row of the batch whose image
differs, or one of the split's first two photos where the whole batch is one photo's) and with a
blank image.

    python -m kosmos_jax.diagnostics.image_use --workdir=runs/demo [--step=N] [--split=test] [--batches=4] [--json]

A model that answers from what it sees has a clearly lower loss on its own images than on another
photo's. Equal losses mean its answers do not depend on the photo: it has learned the marginal
distribution of the answers, whatever its grasp accuracy. Writes WORKDIR/eval/STEP/image_use.json.
"""

from __future__ import annotations

import json
import pathlib
import sys

import jax
import numpy as np
from absl import flags

from kosmos_jax import commands
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.workdir.files import RunError
from kosmos_jax.workdir.run import open_run
from kosmos_jax.train import batches as batches_lib
from kosmos_jax.train.mesh import batch_sharding
from kosmos_jax.train.step import BATCH_KEYS, make_eval_step

IMAGES = ("own", "other", "blank")


def other_images(images: np.ndarray, spares: np.ndarray | None = None) -> np.ndarray:
    """Each row's image replaced by that of the next row (cyclically) whose image differs. The rows of
    one photo's instructions sit side by side and share one image, so a plain roll by one would hand
    every other row its own photo back. A batch that holds one photo only (a photo with more
    instructions than a batch has rows) takes the first of `spares` that differs from it."""
    count = len(images)
    flat = images.reshape(count, -1)
    others = np.empty_like(images)
    for row in range(count):
        shift = next((shift for shift in range(1, count)
                      if not np.array_equal(flat[(row + shift) % count], flat[row])), None)
        if shift is not None:
            others[row] = images[(row + shift) % count]
            continue
        spare = next((spare for spare in ([] if spares is None else spares)
                      if not np.array_equal(spare.reshape(-1), flat[row])), None)
        if spare is None:
            raise ValueError("every row of the batch holds the same image: no other photo's image to swap in")
        others[row] = spare
    return others


def spare_images(batches) -> np.ndarray | None:
    """The first two distinct images of `batches` (None when the split has fewer)."""
    found = []
    for batch in batches:
        for image in batch["image"][batch["example_index"] >= 0]:
            if not any(np.array_equal(image, seen) for seen in found):
                found.append(image)
            if len(found) == 2:
                return np.stack(found)
    return None


def image_use(workdir, step: int | None = None, split: str = "test", batches: int = 4, batch_size: int = 16) -> dict:
    """{"step", "split", "examples", "tokens", "loss": {own, other, blank}, "accuracy": {...}}:
    mean loss (nats) and next-token accuracy on the answer tokens of the first `batches` batches."""
    devices = jax.device_count()
    if batches < 0 or batch_size < 2 or batch_size % devices:
        raise ValueError(f"batches={batches} must be >= 0 (0: the whole split) and batch_size={batch_size} >= 2 "
                         f"(another photo's image comes from the same batch) and a multiple of the {devices} devices")
    run = open_run(workdir)
    mesh = make_mesh(1, -1, 1)
    step, params = run.params(step, mesh)
    eval_step, sharding = make_eval_step(run.model_config, mesh), batch_sharding(mesh)
    totals = {name: {"loss_sum": 0.0, "correct": 0, "tokens": 0} for name in IMAGES}
    examples = 0
    spares = spare_images(batches_lib.eval_batches(run.split(split), batch_size, 0, 1, 0))
    for batch in batches_lib.eval_batches(run.split(split), batch_size, 0, 1, batches):
        examples += int(np.sum(batch["example_index"] >= 0))
        rest = {key: jax.device_put(batch[key], sharding) for key in BATCH_KEYS if key != "image"}
        images = {"own": batch["image"], "other": other_images(batch["image"], spares), "blank": np.zeros_like(batch["image"])}
        for name in IMAGES:
            sums = jax.device_get(eval_step(params, {**rest, "image": jax.device_put(images[name], sharding)}))
            for key in totals[name]:
                totals[name][key] += sums[key].item()
    tokens = totals["own"]["tokens"]
    if not tokens:
        raise ValueError(f"split {split!r} of {workdir} has no answer tokens to score")
    return {"step": step, "split": split, "examples": examples, "tokens": tokens,
            "loss": {name: totals[name]["loss_sum"] / tokens for name in IMAGES},
            "accuracy": {name: totals[name]["correct"] / tokens for name in IMAGES}}


def summary(result: dict) -> str:
    loss, accuracy = result["loss"], result["accuracy"]
    gap = loss["other"] - loss["own"]
    lines = [f"step {result['step']}, {result['split']} split, {result['examples']} examples, "
             f"{result['tokens']} answer tokens"]
    lines += [f"  {name:5s} image: loss {loss[name]:.4f} nats a token, next-token accuracy {accuracy[name]:.4f}"
              for name in IMAGES]
    verdict = ("its answers depend on the photo" if gap > 0.01 * max(loss["own"], 1e-6)
               else "its answers do not depend on the photo (another photo's image scores as well as its own)")
    lines.append(f"another photo's image costs {gap:+.4f} nats a token: {verdict}")
    return "\n".join(lines)


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("string", "workdir", None, "the training run's folder")
    define("integer", "step", None, "checkpoint step (default: the newest)")
    define("string", "split", "test", "a split of the run's dataset")
    define("integer", "batches", 4, "batches scored (0: the whole split)")
    define("integer", "batch_size", 16, "examples a batch")
    define("bool", "json", False, "print the result as one JSON line")
    flags.mark_flag_as_required("workdir", flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_flags, image_use_command, argv,
                                prog="python -m kosmos_jax.diagnostics.image_use", doc=__doc__)


def image_use_command(args) -> int:
    try:
        result = image_use(args.workdir, args.step, args.split, args.batches, args.batch_size)
    except (RunError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    folder = pathlib.Path(args.workdir) / "eval" / str(result["step"])
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "image_use.json").write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result) if args.json else summary(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
