"""Where does a run lose the grasp's angle? Ridge readouts of (cos 2theta, sin 2theta) at three places
of the model, fit on the run's training views and scored on its test views (the share within 30
degrees of the target's angle):

- tower: the vision tower's feature at the patch that holds the target grasp's centre;
- slots: the connector's image slots, averaged (what the decoder is given);
- decoder: the decoder's last hidden state at the position that predicts the angle token, the
  example's own text fed in (teacher forcing); with it `answer`, the angle token the decoder gives
  there, and how many distinct ones.

Each place also reports `angle_share`: the share of its features' variance over the training views
that the angle explains (R^2 of a linear fit on (cos 2theta, sin 2theta)), beside `cell_share`, the
share the grasp's patch cell explains. A readout can find a direction that holds 0.2% of the
variance; a decoder trained by gradient descent learns the large ones first. The untrained model the
run started from (its seed) and the training views' constant mean orientation are the baselines.

    python -m kosmos_jax.diagnostics.angle_probe --workdir=runs/demo [--step=N] [--examples=3000] [--json]

Examples are those whose loss tokens hold an angle token (one per stored view); a vocabulary without
angle value tokens (numbers=digits) has no `decoder` place and reads one example of each view.
"""

from __future__ import annotations

import sys

import jax.numpy as jnp
import numpy as np
from flax import nnx

from kosmos_jax import geometry
from kosmos_jax.diagnostics.readout_command import readout_command
from kosmos_jax.diagnostics.readouts import ridge_fit
from kosmos_jax.models.patch_grid import cell_index, grasp_cell_tokens, grid_side
from kosmos_jax.models.decoder import position_ids
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.models.value_embeddings import angle_token_ids
from kosmos_jax.workdir.files import RunError
from kosmos_jax.workdir.run import open_run

WITHIN_DEG = 30.0
PLACES = ("tower", "slots", "decoder")


@nnx.jit
def _places(model, images, centres, tokens, lengths, image_mask, angle_position):
    """Each example's features at the three places ([B, D] each), its logits [B, V] at `angle_position`
    and its grasp's patch cell [B]."""
    features = model.vision_model(pixels(images, model.config.vision.image_size))
    slots = model.image_to_text_projection(features)
    attention = jnp.arange(tokens.shape[1])[None, :] < lengths[:, None]
    positions = position_ids(attention, model.config.text.pad_token_id)
    hidden, _ = model.text_model.model(tokens, attention, positions, slots, image_mask)
    at_angle = jnp.take_along_axis(hidden, angle_position[:, None, None], axis=1)
    places = {"tower": grasp_cell_tokens(features, centres), "slots": slots.mean(axis=1), "decoder": at_angle[:, 0]}
    cells = cell_index(centres, grid_side(features.shape[1] - 1))
    return places, model.text_model.logits(at_angle)[:, 0], cells


def probe_examples(split, count: int | None, seed: int, angle_ids: np.ndarray) -> list[int]:
    """Indices of examples with a finite target grasp (and, given angle ids, an angle token among their
    loss tokens), one per stored view, `count` of them drawn with `seed`."""
    seen, chosen = set(), []
    for index in np.random.default_rng(seed).permutation(len(split)):
        record = split.examples[int(index)]
        if record["image_index"] in seen or not np.isfinite(np.asarray(record["grasp"], np.float32)).all():
            continue
        if len(angle_ids) and not np.isin(record["tokens"][record["loss_mask"]], angle_ids).any():
            continue
        seen.add(record["image_index"])
        chosen.append(int(index))
        if count is not None and len(chosen) == count:
            break
    return chosen


def read_places(model, split, indices, angle_ids: np.ndarray, batch_size: int = 64) -> dict[str, np.ndarray]:
    """{place: [N, D] features, "answer": [N] the decoder's angle (radians), "angle": [N] the target's,
    "cell": [N] the grasp's patch cell}; one pass over the images for every place."""
    parts = []
    for start in range(0, len(indices), batch_size):
        records = [split[i] for i in indices[start:start + batch_size]]
        images = np.stack([r["image"] for r in records])
        grasps = np.stack([np.asarray(r["grasp"], np.float32) for r in records])
        tokens = np.stack([r["tokens"] for r in records])
        is_angle = np.isin(tokens, angle_ids) & np.stack([r["loss_mask"] for r in records])
        centres = grasps[:, :2] / images.shape[1]
        places, scores, cells = _places(model, jnp.asarray(images), jnp.asarray(centres), jnp.asarray(tokens),
                                 jnp.asarray([r["length"] for r in records]),
                                 jnp.asarray(np.stack([r["image_mask"] for r in records])),
                                 jnp.asarray(np.maximum(is_angle.argmax(axis=1) - 1, 0)))
        part = {name: np.asarray(value, np.float64) for name, value in places.items()}
        if len(angle_ids):
            part["answer"] = geometry.decode_angle(np.asarray(scores)[:, angle_ids].argmax(axis=1))
        part["angle"] = grasps[:, 4].astype(np.float64)
        part["cell"] = np.asarray(cells)
        parts.append(part)
    read = {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}
    if not len(angle_ids):
        read.pop("decoder")
    return read


def doubled(angles: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(2 * angles), np.sin(2 * angles)], axis=1)


def within(read: np.ndarray, angles: np.ndarray) -> float:
    """Share (percent) of readouts [N, 2] whose angle lies within WITHIN_DEG of `angles`."""
    answered = np.arctan2(read[:, 1], read[:, 0]) / 2
    return share_within(answered, angles)


def share_within(answered: np.ndarray, angles: np.ndarray) -> float:
    """Share (percent) of answered angles (radians) within WITHIN_DEG of `angles`."""
    errors = np.degrees(np.asarray(geometry.angle_difference(answered, angles)))
    return round(float((errors <= WITHIN_DEG).mean() * 100), 2)


def ridge_readout(train_x, train_angles, ridge: float):
    """A linear map from standardised features (+ bias) to (cos 2theta, sin 2theta), fit in closed form."""
    return ridge_fit(train_x, doubled(train_angles), ridge)


def explained_share(features: np.ndarray, explanatory: np.ndarray) -> float:
    """R^2: the share of the features' total variance that a least-squares linear map of
    `explanatory` [N, K] (plus a bias) reproduces."""
    design = np.c_[explanatory, np.ones(len(explanatory))]
    fit, *_ = np.linalg.lstsq(design, features, rcond=None)
    centred = features - features.mean(0)
    return round(float(1 - ((features - design @ fit) ** 2).sum() / (centred ** 2).sum()), 4)


def model_readouts(train: dict, test: dict, ridge: float) -> dict:
    """Each place's readout on train and test views and its variance shares; the decoder's own answer."""
    out = {}
    cells = np.eye(int(train["cell"].max()) + 1)[train["cell"]]
    for place in PLACES:
        if place not in train:
            continue
        read = ridge_readout(train[place], train["angle"], ridge)
        out[place] = {"train": within(read(train[place]), train["angle"]), "test": within(read(test[place]), test["angle"]),
                      "angle_share": explained_share(train[place], doubled(train["angle"])),
                      "cell_share": explained_share(train[place], cells)}
    if "answer" in train:
        out["answer"] = {"train": share_within(train["answer"], train["angle"]),
                         "test": share_within(test["answer"], test["angle"]),
                         "distinct_test": int(len(np.unique(test["answer"])))}
    return out


def angle_probe(workdir, step: int | None = None, examples: int = 3000, ridge: float = 0.01, seed: int = 0) -> dict:
    run = open_run(workdir)
    step, params = run.params(step)
    untrained = build(run.model_config, run.config.train.seed)
    graphdef, _, rest = split_model(untrained)
    trained = nnx.merge(graphdef, params, rest)
    angle_ids = angle_token_ids(run.tokenizer.piece_texts())
    train_split, test_split = run.split("train"), run.split("test")
    train_indices = probe_examples(train_split, examples, seed, angle_ids)
    test_indices = probe_examples(test_split, None, seed, angle_ids)
    if len(train_indices) < 2 or not test_indices:
        raise RunError(f"{workdir}: {len(train_indices)} training and {len(test_indices)} test views with a finite "
                       "grasp (and an angle token among the loss tokens); the probe needs at least 2 and 1")
    result = {"step": step, "train_views": len(train_indices), "test_views": len(test_indices), "ridge": ridge}
    for name, model in (("trained", trained), ("untrained", untrained)):
        model = nnx.view(model, deterministic=True)  # the decoder's and the connector's dropout off
        train = read_places(model, train_split, train_indices, angle_ids)
        test = read_places(model, test_split, test_indices, angle_ids)
        result[name] = model_readouts(train, test, ridge)
    mean_direction = doubled(train["angle"]).mean(0, keepdims=True)
    result["constant"] = {"test": within(np.repeat(mean_direction, len(test["angle"]), 0), test["angle"])}
    return result


def main(argv=None) -> int:
    return readout_command(argv, prog="python -m kosmos_jax.diagnostics.angle_probe", doc=__doc__, probe=angle_probe,
                           report=print_report, examples=3000, examples_help="training views the readouts are fit on", least=2)


def print_report(result: dict) -> None:
    print(f"step {result['step']}: share of views within {WITHIN_DEG:.0f} degrees ({result['train_views']} training "
          f"views, {result['test_views']} test views); share of each place's variance the angle and the cell explain")
    for name in ("trained", "untrained"):
        for place, read in result[name].items():
            if place == "answer":
                print(f"  {name} decoder's own answer: test {read['test']}%, train {read['train']}%, "
                      f"{read['distinct_test']} distinct on test")
            else:
                print(f"  {name} {place}: test {read['test']}%, train {read['train']}%, "
                      f"angle share {read['angle_share']}, cell share {read['cell_share']}")
    print(f"  constant mean orientation: test {result['constant']['test']}%")


if __name__ == "__main__":
    sys.exit(main())
