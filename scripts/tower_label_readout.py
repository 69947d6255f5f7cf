"""A tower-label loss's own readout (train.tower_labels) of a run, on scene-stream chunks it never
trained on, by scene (issue 22): does the tower tell the category (or the main colour) of an object
it has not seen, on single photos and on mosaics?

    python scripts/tower_label_readout.py --workdir=runs/pretrain/W [--label=category|colour] \
        [--chunks=900,901] [--step=N]

The chunks are the run's own stream (its config) at numbers past any its training reached (default
900 and 901: seeds stream.seed + 900, ...). Prints one JSON line: per scene, the examples, the share whose
category the fixed directions read right at the target grasp's patch, and the loss's mean
cross-entropy there, for the trained tower and for the run's untrained start.
"""

import argparse
import functools
import json

import jax.numpy as jnp
import numpy as np
from flax import nnx

from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.train import batches, trainer
from kosmos_jax.train.tower_labels import LABEL_NAMES, label_logits
from kosmos_jax.workdir.run import open_run


@functools.partial(nnx.jit, static_argnames="kind")
def tower_logits(model, images, grasp, kind):
    features = model.vision_model(pixels(images, model.config.vision.image_size))
    return label_logits(kind, features, grasp, images.shape[1])


def scores(model, kind, arrays, scene, batch_size=64) -> dict:
    logits = np.concatenate([np.asarray(tower_logits(model, jnp.asarray(arrays["image"][i:i + batch_size]),
                                                     jnp.asarray(arrays["grasp"][i:i + batch_size]), kind=kind))
                             for i in range(0, len(scene), batch_size)])
    labels = arrays[kind]
    shifted = logits - logits.max(1, keepdims=True)
    log_p = shifted - np.log(np.exp(shifted).sum(1, keepdims=True))
    out = {}
    for name in ("single", "multi"):
        rows = scene == name
        out[name] = {"examples": int(rows.sum()),
                     "accuracy": round(100 * float(np.mean(logits[rows].argmax(1) == labels[rows])), 2),
                     "cross_entropy": round(float(-log_p[rows, labels[rows]].mean()), 3)}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--label", default="category", choices=sorted(LABEL_NAMES), help="the label set to read")
    parser.add_argument("--chunks", default="900,901", help="comma-separated chunk numbers of the run's stream")
    parser.add_argument("--step", type=int, default=None, help="checkpoint (default: the newest)")
    args = parser.parse_args()
    run = open_run(args.workdir)
    settings = trainer.stream_settings(run.config.data)
    if settings is None:
        parser.error(f"{args.workdir} did not train on a scene stream")
    stream = trainer.scene_batches(run.config, settings, batches.prepare(run.config.data).tokenizer())
    chunks = [stream.chunk(int(n)) for n in args.chunks.split(",")]
    stream.close()
    arrays = {key: np.concatenate([c.arrays[key] for c in chunks]) for key in ("image", "grasp", args.label)}
    scene = np.asarray(["multi" if "+" in label.split(" (")[0] else "single" for c in chunks for label in c.labels])
    finite = np.isfinite(arrays["grasp"][:, :2]).all(1)
    arrays, scene = {key: value[finite] for key, value in arrays.items()}, scene[finite]
    step, params = run.params(args.step)
    untrained = build(run.model_config, run.config.train.seed)
    graphdef, _, rest = split_model(untrained)
    result = {"workdir": args.workdir, "step": step, "chunks": args.chunks, "label": args.label}
    for name, model in (("trained", nnx.merge(graphdef, params, rest)), ("untrained", untrained)):
        result[name] = scores(nnx.view(model, deterministic=True), args.label, arrays, scene)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
