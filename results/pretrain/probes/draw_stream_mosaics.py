"""Draw four training mosaics of the scene stream's first chunk (one each of the name, colour, shape and
purpose kinds) with their instruction kind, named quadrant and first three target grasps, to check that the
named object and its targets share a quadrant.

    python results/pretrain/probes/draw_stream_mosaics.py results/pretrain/probes/stream_mosaics.jpg
"""

import dataclasses
import importlib.util
import pathlib
import sys
import tempfile

import cv2
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.dataset import build as build_lib
from kosmos_jax.dataset import samples as sample_stage
from kosmos_jax.dataset.inputs import object_words, read_photos, word_source
from kosmos_jax.dataset.views import augment_config, make_views
from kosmos_jax.sources.synthetic import scenes

KINDS = ("name", "colour", "shape", "purpose")
PHOTOS, SEED = 16, 10_000  # a small chunk 0 of configs/pretrain.py's stream


def build_config():
    spec = importlib.util.spec_from_file_location("pretrain", "configs/pretrain.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    build = dict(module.get_config("demo_stream_instruct").data.build)
    fields = {f.name for f in dataclasses.fields(build_lib.BuildConfig)} - {"tokenizer"}
    config = build_lib.BuildConfig(**{k: v for k, v in build.items() if k in fields}, source="-", out="-")
    return dataclasses.replace(config, seed=SEED, kinds=("all",))


def main(out: str) -> None:
    config = build_config()
    single, multi = sample_stage.parse_kinds(config.kinds)
    with tempfile.TemporaryDirectory() as folder:
        source = pathlib.Path(folder) / "scenes"
        scenes.write_dataset(source, photos=PHOTOS, seed=SEED)
        photos, files = read_photos(source)
        words = object_words(word_source(source, None), photos, files)
    made, _ = make_views(photos, words, augment_config(config.augmentations, config.recipe, config.train_crop),
                         SEED, {p.id: i for i, p in enumerate(photos)}, False, config.batch_size)
    drawn = {}
    for _, example in build_lib._examples(config, [made[k] for k in sorted(made)], single, multi, "train"):
        if example.scene != "multi" or example.kind not in KINDS or example.kind in drawn:
            continue
        image = cv2.resize(np.asarray(example.image)[..., ::-1].copy(), (448, 448), interpolation=cv2.INTER_NEAREST)
        corners = np.asarray(geometry.grasps_to_corners(np.asarray(example.answers)[:3])) * 2
        cv2.polylines(image, [c.astype(np.int32).reshape(-1, 1, 2) for c in corners], True, (0, 0, 255), 2)
        cv2.putText(image, f"{example.kind}, quadrant {example.target}", (5, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6,
                    (255, 255, 255), 2)
        print(f"{example.kind}: quadrant {example.target}: {example.instruction}")
        drawn[example.kind] = image
    tiles = [drawn[k] for k in KINDS]
    cv2.imwrite(out, np.concatenate([np.concatenate(tiles[:2], 1), np.concatenate(tiles[2:], 1)], 0),
                [cv2.IMWRITE_JPEG_QUALITY, 80])


if __name__ == "__main__":
    main(sys.argv[1])
