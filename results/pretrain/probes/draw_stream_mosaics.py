"""Draw four training mosaics of the scene stream's first chunk (one each of the name, colour, shape and
purpose kinds) with their instruction kind, named quadrant and first three target grasps, to check that the
named object and its targets share a quadrant.

    python results/pretrain/probes/draw_stream_mosaics.py results/pretrain/probes/stream_mosaics.jpg
"""

import sys

import cv2
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.experiments.spec import load_config
from kosmos_jax.train.batches import build_config
from kosmos_jax.train.scene_stream import scene_examples

KINDS = ("name", "colour", "shape", "purpose")
PHOTOS, SEED = 16, 10_000  # a small chunk 0 of configs/pretrain.py's stream


def main(out: str) -> None:
    build = build_config(load_config("configs/pretrain.py:demo_stream_instruct").data)
    examples, _ = scene_examples(build, PHOTOS, SEED)
    drawn = {}
    for _, example in examples:
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
