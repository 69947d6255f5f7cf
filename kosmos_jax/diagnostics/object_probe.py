"""Where does a run lose the object an instruction names on a mosaic? Ridge readouts at two stages,
fit on the mosaics of the run's training split and scored on its validation split (or test):

- seeing: the vision tower's patch features averaged over each quadrant; read out, for each of the
  four photos, its object's category and its main colour (the words of the object kinds come from
  them); and the tower's feature at the patch that holds the target grasp's centre, read out for the
  named object's category and colour. If these fail, the tower does not see what the words name.
  The same readouts of the pixels (each quadrant averaged to 8 x 8 x 3; the target's patch to
  7 x 7 x 3) say what a readout gets without any tower.
- routing: which quadrant holds the named object, read from the connector's slots (averaged, what
  the decoder is given) and from the decoder's last hidden state where it predicts the answer's
  first token (the example's own text fed in). If the tower sees the objects and these stay near
  chance, the words are not matched to what is seen.

Routing is scored apart for the position kind (whose words name the quadrant itself) and for the
object kinds (name, colour, shape, purpose, strategy). The run's untrained start (its seed) and
the training labels' most common class are the baselines. Needs a run built from synthetic scenes
(their synthetic_meta.json gives each photo's category and colours).

    python -m kosmos_jax.diagnostics.object_probe --workdir=runs/pretrain/W [--step=N] [--examples=2000] [--json]
"""

from __future__ import annotations

import json
import pathlib
import sys

import jax.numpy as jnp
import numpy as np
from flax import nnx

from kosmos_jax.diagnostics.readout_command import readout_command
from kosmos_jax.diagnostics.readouts import accuracy, class_readout, majority_share
from kosmos_jax.models.decoder import position_ids
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.patch_grid import cell_index, grasp_cell_tokens, grid_side
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.sources.synthetic.scenes import META_NAME
from kosmos_jax.workdir.files import RunError
from kosmos_jax.workdir.run import open_run

POSITION_KIND = "position"
ROUTES = ("slots", "decoder")


def quadrant_of_patches(side: int) -> np.ndarray:
    """[side * side] the mosaic quadrant (0 top left, 1 top right, 2 bottom left, 3 bottom right) of
    each patch of a row-major grid."""
    rows, columns = np.divmod(np.arange(side * side), side)
    return 2 * (rows >= side // 2) + (columns >= side // 2)


@nnx.jit
def _stages(model, images, centres, tokens, lengths, image_mask, loss_mask, answer_position):
    """Per quadrant tower features [B, 4, D_vision], the tower's feature at the patch of `centres` [B, D_vision]
    (x, y in units of the side), the slots' mean [B, D] and the decoder's state at `answer_position` [B, D]."""
    features = model.vision_model(pixels(images, model.config.vision.image_size))
    patches = features[:, 1:]
    membership = np.eye(4)[quadrant_of_patches(grid_side(patches.shape[1]))]
    tiles = jnp.einsum("bpd,pq->bqd", patches.astype(jnp.float32), membership / membership.sum(0))
    attention = jnp.arange(tokens.shape[1])[None, :] < lengths[:, None]
    slots = model.image_to_text_projection(features, model.instruction_bag(tokens, attention, image_mask, loss_mask))
    positions = position_ids(attention, model.config.text.pad_token_id)
    hidden, _ = model.text_model.model(tokens, attention, positions, slots, image_mask)
    at_answer = jnp.take_along_axis(hidden, answer_position[:, None, None], axis=1)[:, 0]
    return tiles, grasp_cell_tokens(features, centres), slots.mean(axis=1), at_answer


def quadrant_pixels(images: np.ndarray, side: int = 8) -> np.ndarray:
    """[B, S, S, 3] uint8 mosaics -> [B, 4, side * side * 3]: each quadrant averaged to side x side, in [0, 1]."""
    batch, size = images.shape[0], images.shape[1]
    block = size // (2 * side)
    cropped = images[:, :2 * side * block, :2 * side * block].astype(np.float64) / 255
    pooled = cropped.reshape(batch, 2, side, block, 2, side, block, 3).mean(axis=(3, 6))
    return pooled.transpose(0, 1, 3, 2, 4, 5).reshape(batch, 4, side * side * 3)


def patch_pixels(images: np.ndarray, centres: np.ndarray, side: int, pooled: int = 7) -> np.ndarray:
    """[B, S, S, 3] uint8 images, [B, 2] centres in units of the side -> [B, pooled * pooled * 3]: the
    pixels of the patch (of a side x side grid) holding each centre, averaged to pooled x pooled, in [0, 1]."""
    size = images.shape[1]
    patch = size // side
    block = patch // pooled
    cells = np.asarray(cell_index(centres, side))
    rows, columns = np.divmod(cells, side)
    out = [images[b, r * patch:r * patch + pooled * block, c * patch:c * patch + pooled * block].astype(np.float64)
           .reshape(pooled, block, pooled, block, 3).mean(axis=(1, 3)).reshape(-1) / 255
           for b, (r, c) in enumerate(zip(rows, columns))]
    return np.stack(out)


def text(value) -> str:
    return value.decode() if isinstance(value, bytes) else str(value)


def photo_labels(source: pathlib.Path) -> dict[str, tuple[str, str]]:
    """{photo id: (category, main colour)} from a synthetic source folder's metadata."""
    path = source / META_NAME
    if not path.is_file():
        raise RunError(f"{path} is missing: the object probe needs a run built from synthetic scenes "
                       "(python -m kosmos_jax.sources.synthetic), whose metadata names each photo's object")
    photos = json.loads(path.read_text())["photos"]
    return {photo_id: (meta["category"], meta["colour"][0]) for photo_id, meta in photos.items()}


def mosaic_examples(split, count: int | None, seed: int) -> list[int]:
    """Indices of `count` mosaic examples (all with None) with an answer to predict, drawn with `seed`."""
    chosen = []
    for index in np.random.default_rng(seed).permutation(len(split)):
        record = split.examples[int(index)]
        if text(record["scene"]) != "multi" or not np.asarray(record["loss_mask"]).any():
            continue
        chosen.append(int(index))
        if count is not None and len(chosen) == count:
            break
    return chosen


def read_stages(model, split, indices, batch_size: int = 64) -> dict[str, np.ndarray]:
    """{"tiles": [N, 4, D], "pixels": [N, 4, 192], "at_target": [N, D], "target_pixels": [N, 147], "slots":
    [N, D], "decoder": [N, D], "target": [N] quadrant, "kind": [N], "photos": [N, 4] photo ids}."""
    parts = []
    for start in range(0, len(indices), batch_size):
        records = [split[i] for i in indices[start:start + batch_size]]
        loss_mask = np.stack([r["loss_mask"] for r in records])
        images = np.stack([r["image"] for r in records])
        centres = np.stack([np.asarray(r["grasp"], np.float32)[:2] for r in records]) / images.shape[1]
        tiles, at_target, slots, decoder = _stages(model, jnp.asarray(images), jnp.asarray(centres),
                                        jnp.asarray(np.stack([r["tokens"] for r in records])),
                                        jnp.asarray([r["length"] for r in records]),
                                        jnp.asarray(np.stack([r["image_mask"] for r in records])),
                                        jnp.asarray(loss_mask), jnp.asarray(np.maximum(loss_mask.argmax(axis=1) - 1, 0)))
        side = model.config.vision.image_size // model.config.vision.patch_size
        parts.append({"tiles": np.asarray(tiles, np.float64), "pixels": quadrant_pixels(images),
                      "at_target": np.asarray(at_target, np.float64),
                      "target_pixels": patch_pixels(images, centres, side), "slots": np.asarray(slots, np.float64),
                      "decoder": np.asarray(decoder, np.float64),
                      "target": np.asarray([int(r["target"]) for r in records]),
                      "kind": np.asarray([text(r["kind"]) for r in records]),
                      "photos": np.asarray([[text(p) for p in r["photo_ids"]] for r in records])})
    return {key: np.concatenate([part[key] for part in parts]) for key in parts[0]}


def encode(names: np.ndarray, vocabulary: list[str]) -> np.ndarray:
    return np.asarray([vocabulary.index(name) for name in names])


PLACES = {  # place: (features of each photo's quadrant, or of the target's patch; whose labels)
    "tiles": ("tiles", "every photo"), "pixels": ("pixels", "every photo"),
    "at_target": ("at_target", "target"), "target_pixels": ("target_pixels", "target"),
}


def place_rows(read: dict, place: str) -> tuple[np.ndarray, np.ndarray]:
    """(features [M, D], photo ids [M]) at `place`: four rows a mosaic for its quadrants, one for its target."""
    features, whose = PLACES[place]
    if whose == "target":
        return read[features], read["photos"][np.arange(len(read["target"])), read["target"]]
    return read[features].reshape(-1, read[features].shape[-1]), read["photos"].reshape(-1)


def seeing(train: dict, test: dict, labels: dict, ridge: float, place: str = "tiles") -> dict:
    """The category and main colour of each quadrant's photo (tiles, pixels) or of the target's
    (at_target, target_pixels), read from the features at `place`: test and train accuracy."""
    out = {}
    (train_x, train_photos), (test_x, test_photos) = place_rows(train, place), place_rows(test, place)
    for field, name in ((0, "category"), (1, "colour")):
        train_names = [labels[p][field] for p in train_photos]
        test_names = [labels[p][field] for p in test_photos]
        vocabulary = sorted(set(train_names) | set(test_names))
        train_y, test_y = encode(train_names, vocabulary), encode(test_names, vocabulary)
        read = class_readout(train_x, train_y, len(vocabulary), ridge)
        out[name] = {"test": accuracy(read(test_x), test_y), "train": accuracy(read(train_x), train_y),
                     "majority": majority_share(train_y, test_y), "classes": len(vocabulary)}
    return out


def routing(train: dict, test: dict, ridge: float) -> dict:
    """The target quadrant read from the slots and the decoder, for the position kind and the object kinds."""
    out = {}
    for group, chosen in (("position", lambda kinds: kinds == POSITION_KIND),
                          ("object", lambda kinds: kinds != POSITION_KIND)):
        fit_rows, score_rows = chosen(train["kind"]), chosen(test["kind"])
        if fit_rows.sum() < 2 or not score_rows.any():
            continue
        row = {"test_examples": int(score_rows.sum()),
               "majority": majority_share(train["target"][fit_rows], test["target"][score_rows])}
        for place in ROUTES:
            read = class_readout(train[place][fit_rows], train["target"][fit_rows], 4, ridge)
            row[place] = {"test": accuracy(read(test[place][score_rows]), test["target"][score_rows]),
                          "train": accuracy(read(train[place][fit_rows]), train["target"][fit_rows])}
        out[group] = row
    return out


def object_probe(workdir, step: int | None = None, examples: int = 2000, ridge: float = 0.01, seed: int = 0) -> dict:
    run = open_run(workdir)
    labels = photo_labels(pathlib.Path(run.description["data_identity"]["build"]["source"]["path"]))
    step, params = run.params(step)
    untrained = build(run.model_config, run.config.train.seed)
    graphdef, _, rest = split_model(untrained)
    trained = nnx.merge(graphdef, params, rest)
    train_split = run.split("train")
    try:
        score_name, score_split = "validation", run.split("validation")
    except ValueError:
        score_name, score_split = "test", run.split("test")
    train_indices = mosaic_examples(train_split, examples, seed)
    score_indices = mosaic_examples(score_split, None, seed)
    if len(train_indices) < 8 or not score_indices:
        raise RunError(f"{workdir}: {len(train_indices)} training and {len(score_indices)} {score_name} mosaics; the "
                       "probe needs at least 8 and 1 (a build with the multi kinds)")
    result = {"step": step, "scored_on": score_name, "train_mosaics": len(train_indices),
              "scored_mosaics": len(score_indices), "ridge": ridge}
    for name, model in (("trained", trained), ("untrained", untrained)):
        model = nnx.view(model, deterministic=True)
        train = read_stages(model, train_split, train_indices)
        scored = read_stages(model, score_split, score_indices)
        result[name] = {"seeing": {place: seeing(train, scored, labels, ridge, place) for place in ("tiles", "at_target")},
                        "routing": routing(train, scored, ridge)}
    result["pixels"] = {"seeing": {place: seeing(train, scored, labels, ridge, place)
                                   for place in ("pixels", "target_pixels")}}
    return result


def main(argv=None) -> int:
    return readout_command(argv, prog="python -m kosmos_jax.diagnostics.object_probe", doc=__doc__, probe=object_probe,
                           report=print_report, examples=2000, examples_help="training mosaics the readouts are fit on", least=8)


def print_report(result: dict) -> None:
    print(f"step {result['step']}: readouts fit on {result['train_mosaics']} training mosaics, scored on "
          f"{result['scored_mosaics']} {result['scored_on']} mosaics (accuracy in percent)")
    where = {"tiles": "each quadrant's photo", "at_target": "the target (its patch)",
             "pixels": "each quadrant's photo (8 x 8 pixels)", "target_pixels": "the target (its patch's pixels)"}
    for name in ("trained", "untrained", "pixels"):
        for place, reads in result[name]["seeing"].items():
            for label, read in reads.items():
                print(f"  {name}: {label} of {where[place]}: {read['test']} (train {read['train']}, "
                      f"most common {read['majority']}, {read['classes']} classes)")
        for group, row in result[name].get("routing", {}).items():
            places = ", ".join(f"{place} {row[place]['test']} (train {row[place]['train']})" for place in ROUTES)
            print(f"  {name}: named quadrant, {group} kind(s), {row['test_examples']} mosaics: {places}; "
                  f"most common {row['majority']}")


if __name__ == "__main__":
    sys.exit(main())
