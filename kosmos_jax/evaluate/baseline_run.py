"""A baseline's workdir (config.task "baseline": GR-ConvNet or GG-CNN2), scored as KOSMOS-E's is.

    results, rows, folder = evaluate_baseline(workdir, step=..., split=..., ...)   # run_scores.evaluate's arguments

The views: a split of the run's fold remade from run.json (train.baseline_task.load_views: the
photos of its data source, the same folds, augmentation and keys as in training; the count of test
views must match what training recorded), or with --cornell every photo of a Cornell-format folder
cut as KOSMOS-E's --cornell examples are (dataset.views.HONEST_TEST_CROP: the un-rotated
image-centre crop; honest protocol). The checkpoint's parameters and BatchNorm statistics give one
grasp a view (baselines.family.predict_views: the peak of the blurred quality map; under the run's
`public` protocol the public code's detection, which may find none, on its label-centred crops);
scoring.view_scores scores them with the tally and protocol KOSMOS-E's answers go through (under
`public`, the grasp's own w, h and the pixel-count IoU).
"""

from __future__ import annotations

import dataclasses
import pathlib
import time
from collections.abc import Sequence

import jax
import ml_collections

from kosmos_jax.baselines.family import Family, make_family, predict_views
from kosmos_jax.baselines.inputs import ViewArrays, make_views, needs_depth
from kosmos_jax.dataset.inputs import read_photos
from kosmos_jax.dataset.views import HONEST_TEST_CROP
from kosmos_jax.scoring.view_scores import view_results
from kosmos_jax.instruct.kinds import NON
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.train.baseline_task import abstract_state, family_config, load_views
from kosmos_jax.train import batches as batches_lib
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.workdir.checkpoints import Checkpoints, chosen_step
from kosmos_jax.workdir.files import RunError, read_description, run_task

SPLITS = ("test", "train", "validation")


@dataclasses.dataclass(frozen=True)
class CornellViews:
    views: ViewArrays
    photos: int  # photos read
    views_without_grasps: int
    missing_depth: list[str]  # photos left out: the run's input needs depth they lack


@dataclasses.dataclass(frozen=True)
class BaselineRun:
    workdir: pathlib.Path
    config: ml_collections.ConfigDict
    description: dict  # run.json
    family: Family

    @property
    def protocol(self) -> str:
        return self.config.data.protocol

    @property
    def name(self) -> str:
        return f"{self.family.config.network} ({self.family.config.mode})"

    def weights(self, step: int | None) -> tuple[int, dict]:
        """(step, {"params": ..., "model_state": BatchNorm statistics}) of checkpoint `step` (None: the
        newest), on one device; the optimiser's moments are not read."""
        step = chosen_step(self.workdir, step)
        mesh = make_mesh(1, 1, 1, devices=jax.devices()[:1])
        tx, _ = make_optimizer(self.config.optimizer, self.config.train.steps)  # only to shape the state
        shapes = abstract_state(self.family, tx, mesh)
        with Checkpoints(self.workdir, asynchronous=False) as checkpoints:
            fields = checkpoints.restore_fields(step, {"params": shapes.params, "model_state": shapes.model_state})
        return step, fields

    def source_folder(self) -> pathlib.Path:
        """The photos the run was trained on (run.json's data identity), else where its config finds
        them (synthetic scenes are written again)."""
        recorded = pathlib.Path(self.description["data_identity"]["source"])
        return recorded.resolve() if recorded.is_dir() else batches_lib.source_folder(self.config.data)

    def split(self, name: str) -> ViewArrays:
        """The views of split `name` ("test", "train" or, in a run that held one out, "validation") of the run's fold."""
        if name not in SPLITS:
            raise ValueError(f"unknown split {name!r}; a baseline's fold has {sorted(SPLITS)}")
        if name not in self.description["views"]:
            raise RunError(f"{self.workdir} held out no validation split (config.data.validation_fraction was 0): "
                           "score --split=test or --split=train")
        data = ml_collections.ConfigDict(self.config.data.to_dict())
        data.source = str(self.source_folder())
        views = getattr(load_views(data, self.family.config.mode), name)
        trained = self.description["views"][name]
        if len(views) != trained:
            raise RunError(f"the {name} views remade from {data.source} number {len(views)}, not the {trained} the run "
                           f"was trained with ({self.workdir}/run.json): its photos changed since")
        return views

    def cornell_views(self, folder) -> CornellViews:
        """The honest test view (image-centre crop) of every photo under `folder` that keeps a grasp."""
        photos, _ = read_photos(pathlib.Path(folder))
        mode = self.family.config.mode
        missing = sorted(p.id for p in photos if needs_depth(mode) and p.depth is None)
        usable = [p for p in photos if p.id not in missing]
        if not usable:
            raise ValueError(f"{folder}: no photo has the depth map ({mode} input) this run needs")
        index = {p.id: i for i, p in enumerate(usable)}
        views = make_views(usable, mode, HONEST_TEST_CROP, 0, index, crop_only=True)
        return CornellViews(views, len(photos), views.without_grasps, missing)


def open_baseline_run(workdir) -> BaselineRun:
    workdir = pathlib.Path(workdir)
    description = read_description(workdir)
    if run_task(description) != "baseline":
        raise RunError(f"{workdir} holds a {run_task(description)!r} run, not a baseline's")
    config = ml_collections.ConfigDict(description["config"])
    return BaselineRun(workdir, config, description, make_family(family_config(config.model)))


def first_views(views: ViewArrays, count: int) -> ViewArrays:
    """The first `count` views (0: all)."""
    if not count:
        return views
    return views.select(list(zip(views.photo_id, views.copy))[:count])


def evaluate_baseline(workdir, *, step: int | None, split: str, cornell, kinds: Sequence[str], batch_size: int,
                      max_examples: int) -> tuple[dict, list[dict], pathlib.Path]:
    """(results, one row per view, the folder they belong in): run_scores.evaluate on a baseline's run."""
    started = time.perf_counter()
    run = open_baseline_run(workdir)
    if cornell and list(kinds) != [NON]:
        raise ValueError(f"--kinds={','.join(kinds)}: a baseline ({run.name}) takes no instruction; "
                         f"only {NON!r} can be scored")
    step, weights = run.weights(step)
    if cornell:
        made = run.cornell_views(cornell)
        views, protocol = made.views, "honest"
        label = f"cornell-{pathlib.Path(cornell).resolve().name}"
        source = {"cornell": str(pathlib.Path(cornell).resolve()), "kinds": [NON], "photos": made.photos,
                  "views_without_grasps": made.views_without_grasps, "missing_depth": made.missing_depth}
    else:
        views, protocol, label = run.split(split), run.protocol, split
        source = {"source": str(run.source_folder()), "fold": run.config.data.fold,
                  "scheme": run.config.data.scheme, "missing_depth": run.description["missing_depth"]}
    views = first_views(views, max_examples)
    grasps = predict_views(run.family, weights["params"], weights["model_state"], views, batch_size, protocol)
    figures, rows = view_results(grasps, views, protocol)
    results = {"accuracy": figures.pop("accuracy"), "workdir": str(run.workdir.resolve()), "step": step,
               "split": label, **source, "model": run.name, "network": run.family.config.network,
               "mode": run.family.config.mode, "channels": run.family.config.channels, **figures,
               "max_examples": max_examples, "batch_size": batch_size,
               "seconds": round(time.perf_counter() - started, 2)}
    folder = run.workdir / "eval" / str(step)
    return results, rows, folder if label == "test" else folder / label
