"""Where a run answers one object category's single photos: a probe that draws them.

    python scripts/draw_answers.py --workdir=runs/ft/RUN --scored=cornell-synthetic-300-seed7 \
        --category=Tape [--photos=4] [--out=answers.jpg]

Reads the answers `python -m kosmos_jax.evaluate --workdir=RUN --cornell=FOLDER` wrote (as
`kosmos_jax.diagnostics.categories` does), and for the first --photos single photos of --category
draws the test view (the image-centre crop of the view size, doubled) with every ground-truth centre
(green dots) and the answered centre (red cross), side by side into --out. Prints, over all the
category's answers, the median distance from the answered centre to the nearest ground-truth centre:
a ring answered at its hole lies about its radius from every grasp.
"""

import argparse
import pathlib

import cv2
import numpy as np

from kosmos_jax.diagnostics.answer_errors import read_answers
from kosmos_jax.diagnostics.categories import photo_categories
from kosmos_jax.diagnostics.part_oracles import answered_grasps, nearest_truths, scored_records
from kosmos_jax.scoring.instructions import group_instructions, text
from kosmos_jax.workdir.checkpoints import chosen_step
from kosmos_jax.workdir.run import open_run

SCALE = 2


def drawn(image: np.ndarray, truths: np.ndarray, answer: np.ndarray) -> np.ndarray:
    """The RGB view doubled, as BGR for cv2, with the truths' centres and the answer marked."""
    view = cv2.resize(cv2.cvtColor(image, cv2.COLOR_RGB2BGR), None, fx=SCALE, fy=SCALE,
                      interpolation=cv2.INTER_NEAREST)
    for x, y in truths[:, :2] * SCALE:
        cv2.circle(view, (int(x), int(y)), 3, (0, 200, 0), -1)
    cv2.drawMarker(view, tuple(int(v) for v in answer[:2] * SCALE), (0, 0, 255), cv2.MARKER_CROSS, 12, 2)
    return view


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workdir", required=True, type=pathlib.Path)
    parser.add_argument("--scored", required=True)
    parser.add_argument("--category", required=True)
    parser.add_argument("--photos", type=int, default=4)
    parser.add_argument("--out", default="answers.jpg")
    args = parser.parse_args()
    run = open_run(args.workdir)
    step = chosen_step(args.workdir, None)
    records, _, folder = scored_records(run, step, args.scored)
    categories = photo_categories(folder)
    record_of = lambda instruction: records[min(instruction.examples.values())]
    photo_of = lambda instruction: text(record_of(instruction)["photo_ids"][0])
    single = [i for i in group_instructions(records) if i.scene == "single" and categories[photo_of(i)] == args.category]
    if not single:
        raise SystemExit(f"error: no single-photo instruction of category {args.category!r} in {args.scored}")
    grasps = answered_grasps(single, read_answers(args.workdir, step, args.scored), run.format_config)
    parsed = np.isfinite(grasps).all(axis=1)
    to_nearest = np.hypot(*(nearest_truths(single, grasps)[:, :2] - grasps[:, :2]).T)[parsed]
    print(f"{args.category}: {parsed.sum()} of {len(single)} answers parse; answered centre to the nearest "
          f"ground-truth centre: median {np.median(to_nearest):.1f} px")
    tiles = []
    for instruction, grasp in zip(single, grasps):
        if len(tiles) == args.photos:
            break
        if np.isfinite(grasp).all():
            tiles.append(drawn(record_of(instruction)["image"], instruction.answers, grasp))
    if not tiles:
        raise SystemExit(f"error: no answer of category {args.category!r} parses; nothing to draw")
    cv2.imwrite(args.out, np.concatenate(tiles, axis=1), [cv2.IMWRITE_JPEG_QUALITY, 80])
    print(f"wrote {args.out}: {len(tiles)} photos")


if __name__ == "__main__":
    main()
