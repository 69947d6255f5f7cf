"""`make demo`: train KOSMOS-E on synthetic scenes, score it beside the two no-learning baselines.

    python -m kosmos_jax.demo --config=configs/demo.py [--config.steps=N] [--config.cornell=PATH]

1. Trains `config.train_config` (configs/kosmos_e.py:demo_grounded224_consensus: the demo's small model fine-tuned on
   the project's synthetic scenes, NON and mosaics, at 224 px from the committed grounding start, config.init_from) in
   OUT/run, an ordinary workdir (`python -m kosmos_jax.evaluate --workdir=OUT/run` and the
   notebooks open it); a finished run of the same config is reused (one of another is refused), a
   stopped one resumed.
   With config.init_from (a run's workdir or an exported folder) it fine-tunes from that start.
   It decodes the held-out fold's answers once, with the grammar (evaluate's code; `python -m
   kosmos_jax.evaluate --workdir=OUT/run` adds the decoding without it), and scores the
   image-centre and ground-truth-mean predictors on exactly the same test instructions; it answers each
   mosaic instruction a second time on the quadrant its first answer chose, enlarged 2x, and reports
   that beside the one-pass answers as predictor kosmos_e+zoom (scoring/zoom.py). Then the
   same on config.fresh_photos scenes drawn with another seed (config.fresh_seed), which it never
   trained on: NON on each photo, and the multi-object kinds on four-photo mosaics of them
   (config.fresh_kinds; the evaluate command's --cornell scoring, in OUT/run/eval/STEP/cornell-*).
2. Writes a synthetic Cornell-format set, reads it back with the Cornell reader, and scores the
   two no-learning predictors with 5-fold cross-validation, image-wise and object-wise, under the
   `honest` and `paper` protocols and the `exact` and `reference` IoU backends; the same on the real
   Cornell files when present (../shared/data/cornell, or config.cornell).
Prints both tables and writes OUT/results.json: one row per (data, protocol, split, backend,
scene, predictor), `predictor` = kosmos_e for the trained model (kosmos_e+zoom with the mosaic
zoom). The footnotes say how many views had no ground truth left to score against (skipped) and
how many folds had no scored view.
"""

from __future__ import annotations

import json
import pathlib
import sys
import time

from absl import flags, logging

from kosmos_jax import commands
from kosmos_jax.sources import cornell
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.dataset import views
from kosmos_jax.evaluate.run_scores import evaluate, write
from kosmos_jax.experiments import no_learning, runner, spec
from kosmos_jax.metrics import BACKENDS
from kosmos_jax.scoring import fold_scores
from kosmos_jax.scoring.no_learning import PREDICTORS
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.train.optimizer import check_rates
from kosmos_jax.workdir.files import RunMismatchError
from kosmos_jax.workdir.run import open_run

REPO = pathlib.Path(__file__).resolve().parents[1]
DEFAULT_CORNELL = REPO.parent / "shared" / "data" / "cornell"
GOAL_POINTS = 50  # issue 21's: the held-out fold's single-object instructions, above the image centre
FRESH_SPLIT = "fresh photos"  # the `split` of the rows scored on config.fresh_photos
ZOOMED = "kosmos_e+zoom"  # the demo model with the mosaic zoom (scoring.zoom), a predictor of its tables


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
            folds = fold_scores.view_folds(test_views, scheme, protocol, object_of, k=k, seed=seed)
            for backend in BACKENDS:
                for predictor, predict in PREDICTORS.items():
                    prediction = predict(test_views.grasps, test_views.mask)
                    result = fold_scores.score(prediction, test_views, folds, protocol, backend, k)
                    rows.append(
                        dict(data=name, photos=len(photos), protocol=protocol, split=scheme, backend=backend,
                             scene="all", predictor=predictor, mean=round(result.mean, 2), std=round(result.std, 2),
                             views=result.views, skipped_views=result.skipped_views,
                             empty_folds=result.empty_folds, per_fold=[round(v, 2) for v in result.per_fold])
                    )
    return rows


def trained_rows(config, out: pathlib.Path) -> list[dict]:
    """Train (or reuse) the demo run, then one row per (scene, predictor) on its held-out fold."""
    train_config = spec.load_config(config.train_config)
    if config.steps:
        train_config.train.steps = config.steps
    if config.train_seed >= 0:
        train_config.train.seed = config.train_seed
    if config.peak_lr:  # 0: the training config's own
        train_config.optimizer.peak_lr = config.peak_lr
    check_rates(train_config.optimizer)  # before anything is written
    if config.init_from:
        start = REPO / config.init_from  # an absolute path stays itself
        if not start.is_dir():
            raise FileNotFoundError(f"config.init_from={config.init_from}: folder {start} does not exist")
        train_config.init_from = str(start)
    train_config.data.root = str(out / "datasets")
    train_config.train.grasp_eval_at_end = False  # evaluate_run below decodes the test answers (once)
    workdir = out / "run"
    check_schedule(workdir, train_config, out)
    started = time.perf_counter()
    try:
        summary = runner.default_train(train_config, workdir)
    except RunMismatchError as error:  # e.g. the run of an older make demo's recipe
        raise SystemExit(f"error: {error} (for the demo: remove {out}, or give --config.out=ANOTHER_FOLDER)") from None
    if not summary["finished"]:
        raise SystemExit(f"training stopped at step {summary['step']}: run `make demo` again to resume")
    results = runner.evaluate_run(workdir, summary["step"], unconstrained=False, mosaic_zoom=True)
    no_learning = runner.no_learning_scores(workdir)["scores"]
    build = train_config.data.build
    data = f"{train_config.data.source}-{train_config.data.synthetic_photos}" \
        if train_config.data.source == "synthetic" else train_config.data.source
    rows = scored_rows(dict(data=data, protocol=build.protocol, split=f"{build.split}-fold{build.fold}",
                            step=summary["step"], workdir=str(workdir)), [("kosmos_e", results), *no_learning.items()])
    print(f"trained and scored {workdir} in {time.perf_counter() - started:.0f} s", file=sys.stderr)
    if config.fresh_photos:
        rows += fresh_rows(config, train_config, out, workdir, summary["step"])
    return rows


def check_schedule(workdir: pathlib.Path, train_config, out: pathlib.Path) -> None:
    """Refuse a run left in `workdir` by a make demo of another schedule (400 steps before 2026-12-04): the
    trainer would lengthen it under the new schedule, which is not the demo's recipe."""
    described = workdir / "run.json"
    if not described.is_file():
        return
    from kosmos_jax.train.trainer import schedule_change

    changed = schedule_change(json.loads(described.read_text()), {"config": json.loads(train_config.to_json_best_effort())})
    if changed:
        raise SystemExit(f"error: {workdir} holds a run made with {changed}, another make demo's schedule "
                         f"(for the demo: remove {out}, or give --config.out=ANOTHER_FOLDER)")


def scored_rows(fields: dict, figures_of: list[tuple[str, dict]]) -> list[dict]:
    """One row per (predictor, scene), "all" first, each with `fields`; a decoded model's rows also
    with `angle_at_centre` (percent of its angles within 30 degrees of the ground truth nearest its
    answered centre), and its mosaic zoom's (results' "mosaic_zoom", scoring.zoom) as predictor
    ZOOMED, for the scenes with mosaics."""
    rows = []
    for predictor, figures in figures_of:
        for scene, figure in [("all", figures)] + sorted(figures["by_scene"].items()):
            fit = {"angle_at_centre": figure["angle_at_centre"]["within_30_deg"]} if "angle_at_centre" in figure else {}
            rows.append(dict(fields, backend="exact", scene=scene, predictor=predictor,
                             mean=round(figure["accuracy"], 2), instructions=figure["instructions"], **fit))
        zoomed = figures.get("mosaic_zoom")
        if zoomed and "multi" in zoomed["by_scene"]:
            rows += [dict(fields, backend="exact", scene=scene, predictor=ZOOMED, mean=round(figure["accuracy"], 2),
                          instructions=figure["instructions"])
                     for scene, figure in [("all", zoomed), ("multi", zoomed["by_scene"]["multi"])]]
    return rows


def fresh_rows(config, train_config, out: pathlib.Path, workdir: pathlib.Path, step: int) -> list[dict]:
    """The trained run on scenes drawn with another seed, none of which it trained on: every photo's
    instructions of config.fresh_kinds (NON on the photo, the multi-object kinds on mosaics of
    them), the evaluate command's `--cornell` scoring, beside the no-learning predictors on the same
    instructions."""
    if train_config.data.source == "synthetic" and config.fresh_seed == train_config.data.synthetic_seed:
        raise ValueError(f"config.fresh_seed={config.fresh_seed} is the training scenes' seed: its photos would not be new")
    folder = synthetic_source(out, config.fresh_photos, config.fresh_seed)
    kinds = [kind.strip() for kind in config.fresh_kinds.split(",") if kind.strip()]
    results = fresh_results(workdir, step, folder, kinds)
    run = open_run(workdir)
    records = cornell_examples(folder, run.tokenizer, run.format_config, kinds).records
    no_learning_figures = no_learning.score(records, "honest", run.format_config.image_size)
    fields = dict(data=f"synthetic-{config.fresh_photos}-seed{config.fresh_seed}", protocol="honest",
                  split=FRESH_SPLIT, step=step, workdir=str(workdir))
    return scored_rows(fields, [("kosmos_e", results), *no_learning_figures.items()])


def fresh_results(workdir: pathlib.Path, step: int, folder: pathlib.Path, kinds: list[str]) -> dict:
    """The evaluate command's results for the Cornell-format `folder` (reused when already written
    for these kinds)."""
    written = workdir / "eval" / str(step) / f"cornell-{folder.resolve().name}" / "results.json"
    if written.is_file():
        results = json.loads(written.read_text())
        if results.get("kinds") == kinds and results.get("cornell") == str(folder.resolve()) \
                and "mosaic_zoom" in results:
            return results
    results, answers, where = evaluate(workdir, step=step, cornell=folder, kinds=kinds, unconstrained=False,
                                       mosaic_zoom=True)
    write(results, answers, where)
    return results


def print_trained(rows: list[dict]) -> None:
    """The trained model beside the no-learning predictors on the same instructions: its held-out
    fold (and whether the goal is met), then the fresh photos when they were scored."""
    fold = [r for r in rows if r["split"] != FRESH_SPLIT]
    print_scenes(fold, "held out")
    model = {r["scene"]: r["mean"] for r in fold if r["predictor"] == "kosmos_e"}
    centre = {r["scene"]: r["mean"] for r in fold if r["predictor"] == "image_centre"}
    if "single" in model:
        gain = model["single"] - centre["single"]
        verdict = "met" if gain >= GOAL_POINTS else "NOT met"
        print(f"goal (kosmos_e >= image_centre + {GOAL_POINTS} points on single-object instructions): {verdict}, "
              f"{gain:+.2f} points")
    fresh = [r for r in rows if r["split"] == FRESH_SPLIT]
    if fresh:
        print_scenes(fresh, "(another seed's scenes, never trained on; scene multi: four-photo mosaics of them)")


def print_scenes(rows: list[dict], what: str) -> None:
    """One table: a row per predictor, a column per scene."""
    predictors = sorted({r["predictor"] for r in rows}, key=lambda p: (p not in ("kosmos_e", ZOOMED), p))
    scenes = sorted({r["scene"] for r in rows}, key=lambda s: (s != "all", s))
    first = rows[0]
    print(f"\n{first['data']}, {first['protocol']} protocol, {first['split']} {what}, step {first['step']} "
          f"({first['workdir']}): accuracy in percent (instructions)")
    print(f"{'predictor':<15}" + "".join(f"{'scene ' + s:>18}" for s in scenes))
    cell = {(r["predictor"], r["scene"]): f"{r['mean']:6.2f} ({r['instructions']})" for r in rows}
    for predictor in predictors:
        print(f"{predictor:<15}" + "".join(f"{cell.get((predictor, s), '-'):>18}" for s in scenes))
    fits = {r["scene"]: f"{r['angle_at_centre']:6.2f} ({r['instructions']})" for r in rows if "angle_at_centre" in r}
    if fits:
        print(f"{'(angle fit)':<15}" + "".join(f"{fits.get(s, '-'):>18}" for s in scenes))
        print("angle fit: kosmos_e's angles within 30 degrees of the ground truth nearest its answered centre, in percent")
    if any(r["predictor"] == ZOOMED for r in rows):
        print(f"{ZOOMED}: kosmos_e with each mosaic instruction answered again, as NON, on the quadrant its first "
              "answer chose, enlarged 2x (scoring/zoom.py); single photos as kosmos_e answered them")


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
    trained = trained_rows(config, out) if config.train_config else []
    rows = [row for name, root in sources for row in evaluate_source(name, root, config.seed, config.folds)]
    print_table(rows)
    if trained:
        print_trained(trained)
    rows = trained + rows
    (out / "results.json").write_text(json.dumps(rows, indent=1))
    print(f"\nwrote {out / 'results.json'} in {time.perf_counter() - start:.0f} s")
    return rows


def define_flags(flag_values: flags.FlagValues) -> None:
    commands.define_config(flag_values, "config", str(REPO / "configs" / "demo.py"), "an ml-collections config file")


def demo_command(options) -> int:
    logging.set_verbosity(logging.WARNING)  # orbax and tfds log every file they touch at INFO
    run(options.config)
    return 0


def main(argv=None) -> int:
    return commands.run_command(define_flags, demo_command, argv, prog="python -m kosmos_jax.demo", doc=__doc__)


if __name__ == "__main__":
    sys.exit(main())
