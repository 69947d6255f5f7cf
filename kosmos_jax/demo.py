"""`make demo`: the two no-learning baselines under both protocols and both IoU backends.

    python -m kosmos_jax.demo --config=configs/demo.py [--config.photos=60] [--config.cornell=PATH]

Writes a synthetic Cornell-format set (the project's own data), reads it back with the Cornell
reader, and scores the image-centre predictor and the ground-truth-mean oracle with 5-fold
cross-validation, image-wise and object-wise, under the `honest` and `paper` protocols and the
`exact` and `reference` IoU backends; the same on the real Cornell files when they are present
(../shared/data/cornell, or config.cornell). Prints a table and writes it as JSON to
OUT/baselines.json; both say how many views had no ground truth left to score against (skipped)
and how many folds were left with no scored view (dropped from mean +- std).
"""

from __future__ import annotations

import json
import pathlib
import sys
import time

from absl import app
from ml_collections import config_flags

from kosmos_jax.data import cornell
from kosmos_jax.data.synthetic import scenes
from kosmos_jax.dataset import views
from kosmos_jax.evaluation import baselines, scoring
from kosmos_jax.metrics import BACKENDS

REPO = pathlib.Path(__file__).resolve().parents[1]
DEFAULT_CORNELL = REPO.parent / "shared" / "data" / "cornell"
CONFIG = config_flags.DEFINE_config_file("config", str(REPO / "configs" / "demo.py"), "an ml-collections config file")


def synthetic_source(out: pathlib.Path, photos: int, seed: int) -> pathlib.Path:
    """The synthetic set under OUT, made once per (photos, seed) and reused after. A set without
    synthetic_meta.json (an older version stopped while writing it) is written again; anything else
    in the way is an error (write_dataset's), never deleted."""
    root = out / f"synthetic_{photos}_seed{seed}"
    if (root / scenes.META_NAME).exists():
        return root
    print(f"writing {photos} synthetic photos to {root}", file=sys.stderr)
    scenes.write_dataset(root, photos=photos, seed=seed, overwrite=True, progress=True)
    return root


def evaluate_source(name: str, root: pathlib.Path, seed: int, k: int = 5) -> list[dict]:
    photos = cornell.load_photos(root, progress=True)
    object_of = {p.id: p.object_id for p in photos}
    rows = []
    for protocol in views.PROTOCOLS:
        test_views = views.evaluation_views(photos, protocol, seed=seed, progress=True)
        for scheme in ("image", "object"):
            folds = scoring.view_folds(test_views, scheme, protocol, object_of, k=k, seed=seed)
            for backend in BACKENDS:
                for predictor, predict in baselines.BASELINES.items():
                    prediction = predict(test_views.grasps, test_views.mask)
                    result = scoring.score(prediction, test_views, folds, protocol, backend, k)
                    rows.append(
                        dict(data=name, photos=len(photos), protocol=protocol, split=scheme, backend=backend,
                             predictor=predictor, mean=round(result.mean, 2), std=round(result.std, 2),
                             views=result.views, skipped_views=result.skipped_views,
                             empty_folds=result.empty_folds, per_fold=[round(v, 2) for v in result.per_fold])
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
    print(skipped_note(rows))


def skipped_note(rows: list[dict]) -> str:
    """Footnote: views not scored (no ground truth left in them) and folds left out of the mean."""
    counts = {(r["data"], r["protocol"], r["split"]): (r["skipped_views"], r["views"], r["empty_folds"]) for r in rows}
    parts = [f"{data} {protocol} {split}-wise: {skipped} of {skipped + views} views skipped, {empty} empty folds"
             for (data, protocol, split), (skipped, views, empty) in sorted(counts.items()) if skipped or empty]
    if not parts:
        return "every view had ground truth to score against; no fold was empty"
    return ("not scored (no ground truth left in the view; a fold with no scored view is left out of "
            "mean +- std): " + "; ".join(parts))


def run(config) -> list[dict]:
    """Make or reuse the synthetic set, evaluate every source, print and save the table."""
    start = time.perf_counter()
    out = REPO / config.out
    out.mkdir(parents=True, exist_ok=True)
    sources = [("synthetic", synthetic_source(out, config.photos, config.seed))]
    cornell_root = pathlib.Path(config.cornell) if config.cornell else DEFAULT_CORNELL
    if cornell_root.exists():
        sources.append(("cornell", cornell_root))
    elif config.cornell:
        raise FileNotFoundError(f"config.cornell={config.cornell!r} does not exist")
    else:
        print(f"no Cornell files at {cornell_root}: synthetic data only", file=sys.stderr)
    rows = [row for name, root in sources for row in evaluate_source(name, root, config.seed, config.folds)]
    print_table(rows)
    (out / "baselines.json").write_text(json.dumps(rows, indent=1))
    print(f"\nwrote {out / 'baselines.json'} in {time.perf_counter() - start:.0f} s")
    return rows


def main(argv) -> None:
    if len(argv) > 1:
        raise app.UsageError(f"unexpected arguments: {argv[1:]}")
    run(CONFIG.value)


if __name__ == "__main__":
    app.run(main)
