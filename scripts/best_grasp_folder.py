"""A copy of a synthetic folder whose photos each keep one positive grasp, the annotation's expected best, a probe (issue 22).

    python scripts/best_grasp_folder.py --cornell=datasets/synthetic-1200-seed0 --out=datasets/synthetic-1200-seed0-best \
        [--draws=40] [--candidates=160]

A synthetic photo's positive grasps are one draw of its annotation (sources/synthetic/scenes.draw_positives). A model
trained on such draws meets, for the same photo, a target that moves from draw to draw. This writes the targets
that do not move: for each photo the generator poses the object again, draws its annotation DRAWS times for
candidate grasps (at most CANDIDATES of them) and DRAWS times more to score them, and keeps the candidate that hits
the most of the second draws (the rectangle metric with each ground truth's own w and h, as the honest protocol
scores; in photo pixels, where the honest test view's crop moves every grasp alike). Its rectangle becomes the
photo's only rectangle in cposNNNN.txt, and its part the photo's only `grasp_parts` entry in synthetic_meta.json;
everything else is copied as it is.

Privileged: only the generator can draw an annotation again, so this is a diagnosis (what the model learns from
targets that do not move), not a recipe for photos the project did not make. Scoring never reads this folder.
"""

import argparse
import json
import pathlib
import shutil
import sys

import numpy as np

from kosmos_jax import geometry
from kosmos_jax.diagnostics.annotation_draws import hit_rates, padded
from kosmos_jax.diagnostics.categories import synthetic_header
from kosmos_jax.sources.synthetic import scenes


def best_grasp(seed: int, index: int, draws: int, candidates: int) -> tuple[np.ndarray, str, float]:
    """(x, y, w, h, theta) of photo `index`'s expected best grasp, its part, and its hit rate on the scoring draws."""
    _, posed = scenes.posed_photo(seed, index)
    rng = np.random.default_rng([seed, index, 5])
    grasps, parts = [], []
    for _ in range(draws):
        drawn, parts_of = scenes.draw_positives(rng, posed)
        grasps.extend(drawn)
        parts.extend(parts_of)
    chosen = rng.permutation(len(grasps))[:candidates]
    pool = np.asarray(grasps, np.float32).reshape(-1, 5)[chosen]
    scoring = padded([scenes.draw_positives(rng, posed)[0] for _ in range(draws)])
    rates = hit_rates(pool[:, [0, 1, 4]], *scoring)
    best = int(np.argmax(rates))
    return pool[best], parts[chosen[best]], float(rates[best])


def write_folder(source, out, draws: int = 40, candidates: int = 160) -> list[float]:
    source, out = pathlib.Path(source), pathlib.Path(out)
    header = synthetic_header(source, "only folders written by python -m kosmos_jax.sources.synthetic can be drawn again")
    if out.exists():
        raise SystemExit(f"error: {out} exists")
    shutil.copytree(source, out)
    rates = []
    meta = json.loads((source / scenes.META_NAME).read_text())
    for number, photo in enumerate(sorted(header["photos"]), start=1):
        index = int(photo.removeprefix("pcd")) - scenes.FIRST_NUMBER
        grasp, part, rate = best_grasp(header["seed"], index, draws, candidates)
        rates.append(rate)
        meta["photos"][photo]["grasp_parts"] = [part]
        folder = out / header["photos"][photo]["folder"]
        (folder / f"{photo}cpos.txt").write_text(scenes.format_rectangles(geometry.grasps_to_corners(grasp[None])))
        if number % 100 == 0 or number == len(header["photos"]):
            print(f"{number}/{len(header['photos'])} photos, mean expected hit rate {np.mean(rates):.4f}",
                  file=sys.stderr, flush=True)
    (out / scenes.META_NAME).write_text(json.dumps(meta, indent=1))
    return rates


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cornell", required=True, help="a folder written by python -m kosmos_jax.sources.synthetic")
    parser.add_argument("--out", required=True)
    parser.add_argument("--draws", type=int, default=40)
    parser.add_argument("--candidates", type=int, default=160)
    args = parser.parse_args(argv)
    rates = write_folder(args.cornell, args.out, args.draws, args.candidates)
    print(f"wrote {args.out}: {len(rates)} photos, one positive each; mean expected hit rate {np.mean(rates):.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
