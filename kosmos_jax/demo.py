"""`make demo`: the two no-learning baselines under both protocols and both IoU backends.

    python -m kosmos_jax.demo [--out demo_out] [--photos 60] [--seed 0] [--cornell PATH]

Writes a synthetic Cornell-format set (the project's own data), reads it back with the Cornell
reader, and scores the image-centre predictor and the ground-truth-mean oracle with 5-fold
cross-validation, image-wise and object-wise, under the `honest` and `paper` protocols and the
`exact` and `reference` IoU backends; the same on the real Cornell files when they are present
(../shared/data/cornell, or --cornell). Prints a table and writes it as JSON to OUT/baselines.json.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

from kosmos_jax.data import cornell, synthetic
from kosmos_jax.evaluation import baselines, scoring, views
from kosmos_jax.metrics import BACKENDS

REPO = pathlib.Path(__file__).resolve().parents[1]
DEFAULT_CORNELL = REPO.parent / "shared" / "data" / "cornell"


def synthetic_source(out: pathlib.Path, photos: int, seed: int) -> pathlib.Path:
    """The synthetic set under OUT, made once per (photos, seed) and reused after."""
    root = out / f"synthetic_{photos}_seed{seed}"
    if not (root / "synthetic_meta.json").exists():
        print(f"writing {photos} synthetic photos to {root}", file=sys.stderr)
        synthetic.write_dataset(root, photos=photos, seed=seed, overwrite=root.exists(), progress=True)
    return root


def evaluate_source(name: str, root: pathlib.Path, seed: int) -> list[dict]:
    photos = cornell.load_photos(root, progress=True)
    object_of = {p.id: p.object_id for p in photos}
    rows = []
    for protocol in views.PROTOCOLS:
        test_views = views.make_views(photos, protocol, seed=seed, progress=True)
        for scheme in ("image", "object"):
            folds = scoring.view_folds(test_views, scheme, protocol, object_of, seed=seed)
            for backend in BACKENDS:
                for predictor, predict in baselines.BASELINES.items():
                    result = scoring.score(predict(test_views.grasps, test_views.mask), test_views, folds, protocol, backend)
                    rows.append(
                        dict(data=name, photos=len(photos), protocol=protocol, split=scheme, backend=backend,
                             predictor=predictor, mean=round(result.mean, 2), std=round(result.std, 2),
                             views=result.views, per_fold=[round(v, 2) for v in result.per_fold])
                    )
    return rows


def print_table(rows: list[dict]) -> None:
    header = f"{'data':<10} {'protocol':<8} {'backend':<10} {'predictor':<15} {'image-wise':>16} {'object-wise':>16}"
    print(header)
    print("-" * len(header))
    keys = sorted({(r["data"], r["protocol"], r["backend"], r["predictor"]) for r in rows}, key=lambda k: (k[0], k[1], k[2], k[3]))
    for data, protocol, backend, predictor in keys:
        cells = {r["split"]: f"{r['mean']:6.2f} +- {r['std']:5.2f}" for r in rows
                 if (r["data"], r["protocol"], r["backend"], r["predictor"]) == (data, protocol, backend, predictor)}
        print(f"{data:<10} {protocol:<8} {backend:<10} {predictor:<15} {cells['image']:>16} {cells['object']:>16}")
    print("\nrectangle metric (angle <= 30 deg, IoU > 0.25), 5-fold mean +- std in percent; "
          "honest: photo-centre crops, w/h from each ground truth; paper: label-centred augmented crops, "
          "w = widest opening, h = mean jaw (KOSMOS-E's code)")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=pathlib.Path, default=REPO / "demo_out")
    parser.add_argument("--photos", type=int, default=60, help="synthetic photos to make (default 60)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cornell", type=pathlib.Path, default=DEFAULT_CORNELL,
                        help="a Cornell-format folder to evaluate as well, when it exists")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    sources = [("synthetic", synthetic_source(args.out, args.photos, args.seed))]
    if args.cornell.exists():
        sources.append(("cornell", args.cornell))
    else:
        print(f"no Cornell files at {args.cornell}: synthetic data only", file=sys.stderr)
    rows = [row for name, root in sources for row in evaluate_source(name, root, args.seed)]
    print_table(rows)
    (args.out / "baselines.json").write_text(json.dumps(rows, indent=1))
    print(f"\nwrote {args.out / 'baselines.json'} in {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
