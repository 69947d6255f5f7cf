"""A copy of a synthetic folder whose photos each keep one positive grasp, the annotation's expected best, a probe (issue 22).

    python scripts/best_grasp_folder.py --cornell=datasets/synthetic-1200-seed0 --out=datasets/synthetic-1200-seed0-best \
        [--draws=40] [--candidates=160]

Each photo keeps only the grasp that `kosmos_jax.sources.synthetic.best_grasps.best_grasp` chooses (the one
answer that hits the most fresh draws of its annotation); everything else is copied as it is. Privileged: only
the generator can draw an annotation again, so a model fine-tuned on this folder says what targets that do not
move teach, not how to train on photos the project did not make. Scoring never reads this folder.
"""

import argparse
import pathlib
import shutil
import sys

import numpy as np

from kosmos_jax.diagnostics.categories import synthetic_header
from kosmos_jax.sources.synthetic.best_grasps import keep_best_grasps


def write_folder(source, out, draws: int = 40, candidates: int = 160) -> list[float]:
    source, out = pathlib.Path(source), pathlib.Path(out)
    synthetic_header(source, "only folders written by python -m kosmos_jax.sources.synthetic can be drawn again")
    if out.exists():
        raise SystemExit(f"error: {out} exists")
    shutil.copytree(source, out)
    return keep_best_grasps(out, draws, candidates, progress=True)


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
