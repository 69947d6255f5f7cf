"""Each synthetic photo's expected best grasp: the one answer that hits the most draws of its annotation.

A synthetic photo's positive grasps are one draw (scenes.draw_positives: 2 to 7 grasps at random places on its
graspable parts), so a model trained on such draws meets, for one photo, a target that moves from draw to draw.
The generator can pose a photo's object again and draw its annotation as often as asked: `best_grasp` draws it
DRAWS times for candidate grasps (at most CANDIDATES of them) and DRAWS times more to score them, and keeps the
candidate that hits the most of the second set (the rectangle metric with each ground truth's own w and h, as the
honest protocol scores; in photo pixels, where the test view's crop moves every grasp alike).
`keep_best_grasps` rewrites a folder the generator wrote so that each photo keeps only that grasp: its cposNNNN.txt
one rectangle, its `grasp_parts` in synthetic_meta.json one part. Only scenes the project makes can be treated so.
"""

from __future__ import annotations

import json
import pathlib
import sys
from collections.abc import Sequence

import numpy as np

from kosmos_jax import geometry
from kosmos_jax.metrics.success import grasp_success
from kosmos_jax.sources.synthetic import scenes

MAX_POSITIVES = max(scenes.POSITIVES[0])


def padded(draws: Sequence[Sequence[np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """(grasps [D, MAX_POSITIVES, 5], mask [D, MAX_POSITIVES]) of draws of grasps (x, y, w, h, theta), as drawn."""
    grasps = np.zeros((len(draws), MAX_POSITIVES, 5), np.float32)
    mask = np.zeros((len(draws), MAX_POSITIVES), bool)
    for row, draw in enumerate(draws):
        grasps[row, :len(draw)] = np.asarray(draw, np.float32).reshape(-1, 5)
        mask[row, :len(draw)] = True
    return grasps, mask


def hit_rates(answers: np.ndarray, grasps: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """[A] the share of draws each answer (x, y, theta) [A, 3] hits, honest protocol, against draws [D, M, 5]."""
    count, draws = len(answers), len(grasps)
    pred = np.repeat(answers, draws, axis=0)
    hits = grasp_success(pred, np.tile(grasps, (count, 1, 1)), np.tile(mask, (count, 1)), wh_policy="per_gt")
    return np.asarray(hits).reshape(count, draws).mean(axis=1)


def best_grasp(seed: int, index: int, draws: int = 24, candidates: int = 96) -> tuple[np.ndarray, str, float]:
    """(x, y, w, h, theta) of photo `index` (of the set written with `seed`)'s expected best grasp, its part,
    and its hit rate on the scoring draws."""
    _, posed = scenes.posed_photo(seed, index)
    rng = np.random.default_rng([seed, index, 5])
    grasps, parts = [], []
    for _ in range(draws):
        drawn, parts_of = scenes.draw_positives(rng, posed)
        grasps.extend(drawn)
        parts.extend(parts_of)
    if not grasps:
        raise ValueError(f"photo {index} of seed {seed}: none of {draws} draws of its annotation holds a grasp")
    chosen = rng.permutation(len(grasps))[:candidates]
    pool = np.asarray(grasps, np.float32).reshape(-1, 5)[chosen]
    rates = hit_rates(pool[:, [0, 1, 4]], *padded([scenes.draw_positives(rng, posed)[0] for _ in range(draws)]))
    best = int(np.argmax(rates))
    return pool[best], parts[chosen[best]], float(rates[best])


def keep_best_grasps(folder, draws: int = 24, candidates: int = 96, progress: bool = False) -> list[float]:
    """Rewrite `folder` (written by the generator) in place: each photo keeps only its expected best grasp.
    Returns each photo's best hit rate."""
    folder = pathlib.Path(folder)
    meta = json.loads((folder / scenes.META_NAME).read_text())
    rates = []
    for number, (photo, about) in enumerate(sorted(meta["photos"].items()), start=1):
        grasp, part, rate = best_grasp(meta["seed"], int(photo.removeprefix("pcd")) - scenes.FIRST_NUMBER,
                                       draws, candidates)
        (folder / about["folder"] / f"{photo}cpos.txt").write_text(
            scenes.format_rectangles(geometry.grasps_to_corners(grasp[None])))
        about["grasp_parts"] = [part]
        rates.append(rate)
        if progress and (number % 100 == 0 or number == len(meta["photos"])):
            print(f"best grasps: {number}/{len(meta['photos'])} photos, mean expected hit rate {np.mean(rates):.4f}",
                  file=sys.stderr, flush=True)
    (folder / scenes.META_NAME).write_text(json.dumps(meta, indent=1))
    return rates
