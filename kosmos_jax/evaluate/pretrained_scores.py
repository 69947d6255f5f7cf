"""An exported folder (workdir.export: weights, tokenizer.model and kosmos_e.json) scored on every
photo of a Cornell-format folder, as a run's workdir is scored with --cornell.

    results, rows, folder = evaluate_pretrained("results/pretrain/grounding14000", cornell="photos/",
                                                kinds=("non", "multi"), out="runs/evaluate/grounding14000")

The folder is read as `GraspPredictor.from_pretrained` reads an exported folder (its text format,
tokenizer and windows from kosmos_e.json, by workdir.exported.folder_settings) and decoded by the same GraspEvaluation as a workdir, under the honest
protocol. The files go to `out`/cornell-NAME, never into the exported folder itself (a shipped start
stays as it was committed).
"""

from __future__ import annotations

import os
import pathlib
import time
from collections.abc import Sequence

import jax
from jax.sharding import NamedSharding, PartitionSpec

from kosmos_jax.instruct.kinds import NON
from kosmos_jax.models.kosmos2 import split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_decoding import WINDOWS, chosen_windows
from kosmos_jax.models.weights import load_pretrained
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.text.tokenizer import load_tokenizer
from kosmos_jax.workdir.exported import folder_settings
from kosmos_jax.workdir.files import RunError

DEFAULT_OUT = pathlib.Path("runs") / "evaluate"  # + the folder's name, relative to the working directory


def evaluate_pretrained(pretrained: str | os.PathLike, *, cornell: str | os.PathLike,
                        kinds: Sequence[str] = (NON,), out: str | os.PathLike | None = None, batch_size: int = 16,
                        max_examples: int = 0, value_window: int | None = None,
                        angle_window: int | None = None, unconstrained: bool = True,
                        mosaic_zoom: bool = False) -> tuple[dict, list[dict], pathlib.Path]:
    """(results, one row per example, the folder to write them to) of the exported folder
    `pretrained` on every photo of `cornell`. `out` (default runs/evaluate/NAME) must lie outside
    `pretrained`; value_window / angle_window None: as kosmos_e.json says; `unconstrained` False:
    decoded with the grammar only; `mosaic_zoom`: also the mosaics answered again on their chosen
    quadrant (scoring.zoom)."""
    if batch_size < 1 or max_examples < 0:
        raise ValueError("batch_size must be positive and max_examples at least 0")
    started = time.perf_counter()
    pretrained = pathlib.Path(pretrained)
    if not pretrained.is_dir():
        raise FileNotFoundError(f"--pretrained={pretrained}: no such folder")
    settings = folder_settings(pretrained)
    if not settings:
        raise RunError(f"{pretrained} holds no kosmos_e.json: only a folder exported from a run "
                       "(python -m kosmos_jax.workdir.export) says how it was trained to be asked")
    base = pathlib.Path(out) if out else DEFAULT_OUT / pretrained.resolve().name
    if base.resolve().is_relative_to(pretrained.resolve()):
        raise ValueError(f"--out={base} lies inside --pretrained={pretrained}: write the scores elsewhere, the "
                         "exported folder stays as it was made")
    if not settings["tokenizer"].is_file():
        raise RunError(f"{settings['tokenizer']} is missing: an exported folder holds its run's tokenizer; export it again")
    tokenizer = load_tokenizer(settings["tokenizer"], scheme=settings["scheme"], numbers=settings["numbers"])
    config = settings["format_config"]
    made = cornell_examples(cornell, tokenizer, config, kinds)
    mesh = make_mesh(1, -1, 1)
    model = load_pretrained(pretrained)
    params = jax.device_put(split_model(model)[1], NamedSharding(mesh, PartitionSpec()))
    windows = chosen_windows({name: settings[name] for name in WINDOWS}, value_window=value_window,
                             angle_window=angle_window)
    evaluation = GraspEvaluation(model.config, mesh, made.records, tokenizer, config, "honest",
                                 batch_size=batch_size, max_examples=max_examples, **windows)
    figures, rows = evaluation.results(params, unconstrained=unconstrained, mosaic_zoom=mosaic_zoom)
    label = f"cornell-{pathlib.Path(cornell).resolve().name}"
    results = {"accuracy": figures.pop("accuracy"), "pretrained": str(pretrained.resolve()),
               "step": settings["step"], "split": label, "cornell": str(pathlib.Path(cornell).resolve()),
               "kinds": list(kinds), "photos": made.photos, "views_without_grasps": made.views_without_grasps,
               "representation": config.representation, "individual": config.individual,
               "angle_code": config.angle_code, **figures, "max_examples": max_examples, "batch_size": batch_size,
               **windows, "seconds": round(time.perf_counter() - started, 2)}
    return results, rows, base / label
