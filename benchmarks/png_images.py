"""The build's image table: PNG encoding with zlib's run-length strategy against its default
strategy, and the mosaic's 2 x 2 halving by OpenCV against numpy arithmetic, in the same run.

    .venv/bin/python benchmarks/png_images.py [--photos 24] [--seed 0] [--repeats 5]

Draws `--photos` synthetic scenes, makes the demo's test views of them (honest protocol, photo-centre
crops, 224 px) and four-photo mosaics of those views, then times each way of encoding them (best
of --repeats rounds over every image, the two ways taking turns within a round) and of decoding the bytes back, with the bytes' mean size,
and checks that every way decodes to the same pixels. The halving is timed on the mosaics' tiled
448 px images, and its two ways are checked equal pixel for pixel.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time

import cv2
import numpy as np

from kosmos_jax.dataset import views
from kosmos_jax.dataset.images import decode_png, png_bytes
from kosmos_jax.instruct.mosaic import downsample_2x, tile_images
from kosmos_jax.sources import cornell
from kosmos_jax.sources.synthetic import scenes

DEFAULT_STRATEGY = [cv2.IMWRITE_PNG_COMPRESSION, 1]  # the project's encoding before the run-length strategy


def best_seconds(calls: dict, items, repeats: int) -> dict:
    """name -> the best over `repeats` rounds of the mean seconds of call(item) over every item; the
    calls take turns within each round, so a neighbour's load falls on each alike."""
    best = dict.fromkeys(calls, float("inf"))
    for _ in range(repeats):
        for name, call in calls.items():
            start = time.perf_counter()
            for item in items:
                call(item)
            best[name] = min(best[name], (time.perf_counter() - start) / len(items))
    return best


def default_png(rgb: np.ndarray) -> bytes:
    return cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]), DEFAULT_STRATEGY)[1].tobytes()


def halve_by_arithmetic(image: np.ndarray) -> np.ndarray:
    """downsample_2x's numpy path: uint16 sums of the four corners, rounded half up."""
    corners = [image[i::2, j::2, :].astype(np.uint16) for i in (0, 1) for j in (0, 1)]
    return (((corners[0] + corners[1]) + (corners[2] + corners[3]) + 2) // 4).astype(np.uint8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--photos", type=int, default=24)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        scenes.write_dataset(scratch, photos=args.photos, seed=args.seed, overwrite=True)
        photos = cornell.load_photos(scratch)
        test_views = views.evaluation_views(photos, "honest", seed=args.seed)
    singles = [np.asarray(image) for image in test_views.images]
    tiled = [tile_images(singles[i:i + 4]) for i in range(0, len(singles) - 3)]
    images = singles + [downsample_2x(t) for t in tiled]
    encoded = {"run-length (ours)": [png_bytes(i) for i in images], "default strategy (peer)": [default_png(i) for i in images]}
    for data in encoded.values():
        assert all((decode_png(b) == i).all() for b, i in zip(data, images)), "an encoding changed the pixels"
    for halved, image in zip(tiled, images[len(singles):]):
        assert (halve_by_arithmetic(halved) == image).all(), "the two halvings differ"
    ours, peer = best_seconds({"ours": png_bytes, "peer": default_png}, images, args.repeats).values()
    decode = {name: min(best_seconds({name: lambda i, data=data: decode_png(data[i])}, range(len(data)),
                                     args.repeats).values()) for name, data in encoded.items()}
    halve_ours, halve_peer = best_seconds({"ours": downsample_2x, "peer": halve_by_arithmetic}, tiled,
                                          args.repeats).values()
    record = {
        "images": len(images), "shape": list(images[0].shape),
        "encode_ms": {"ours": round(ours * 1e3, 3), "peer": round(peer * 1e3, 3), "peer_over_ours": round(peer / ours, 2)},
        "decode_ms": {name: round(s * 1e3, 3) for name, s in decode.items()},
        "mean_kb": {name: round(sum(map(len, data)) / len(data) / 1e3, 1) for name, data in encoded.items()},
        "halve_448px_ms": {"opencv (ours)": round(halve_ours * 1e3, 3), "numpy (peer)": round(halve_peer * 1e3, 3),
                           "peer_over_ours": round(halve_peer / halve_ours, 2)},
    }
    print(f"PNG encode: {record['encode_ms']['ours']} ms an image (run-length) against {record['encode_ms']['peer']} "
          f"(default strategy): x{record['encode_ms']['peer_over_ours']}; decode {record['decode_ms']}; "
          f"size {record['mean_kb']} KB")
    print(f"mosaic halving of a 448 px image: {record['halve_448px_ms']}")
    print(json.dumps(record))


if __name__ == "__main__":
    main()
