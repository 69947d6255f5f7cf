"""An exported folder (workdir.export: weights, tokenizer.model and kosmos_e.json) scored on every
photo of a Cornell-format folder, as a run's workdir is scored with --cornell.

    results, rows, folder = evaluate_pretrained("results/pretrain/grounding10000", cornell="photos/",
                                                kinds=("non", "multi"), out="runs/evaluate/grounding10000")

The folder is read as `GraspPredictor.from_pretrained` reads it (its text format, tokenizer and
windows from kosmos_e.json) and decoded by the same GraspEvaluation as a workdir, under the honest
protocol. The files go to `out`/cornell-NAME, never into the exported folder itself (a shipped start
stays as it was committed).
"""

from __future__ import annotations

import os
import pathlib
import time
from collections.abc import Sequence

from kosmos_jax.instruct.kinds import NON
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.predict.errors import RunFolderError
from kosmos_jax.predict.predictor import GraspPredictor
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.workdir.pretrained import read_description

DEFAULT_OUT = pathlib.Path("runs") / "evaluate"  # + the folder's name, relative to the working directory


def evaluate_pretrained(pretrained: str | os.PathLike, *, cornell: str | os.PathLike,
                        kinds: Sequence[str] = (NON,), out: str | os.PathLike | None = None, batch_size: int = 16,
                        max_examples: int = 0, value_window: int | None = None,
                        angle_window: int | None = None) -> tuple[dict, list[dict], pathlib.Path]:
    """(results, one row per example, the folder to write them to) of the exported folder
    `pretrained` on every photo of `cornell`. `out` (default runs/evaluate/NAME) must lie outside
    `pretrained`; value_window / angle_window None: as kosmos_e.json says."""
    if batch_size < 1 or max_examples < 0:
        raise ValueError("batch_size must be positive and max_examples at least 0")
    started = time.perf_counter()
    pretrained = pathlib.Path(pretrained)
    if not pretrained.is_dir():
        raise FileNotFoundError(f"--pretrained={pretrained}: no such folder")
    described = read_description(pretrained)
    if described is None:
        raise RunFolderError(f"{pretrained} holds no kosmos_e.json: only a folder exported from a run "
                             "(python -m kosmos_jax.workdir.export) says how it was trained to be asked")
    base = pathlib.Path(out) if out else DEFAULT_OUT / pretrained.resolve().name
    if base.resolve().is_relative_to(pretrained.resolve()):
        raise ValueError(f"--out={base} lies inside --pretrained={pretrained}: write the scores elsewhere, the "
                         "exported folder stays as it was made")
    mesh = make_mesh(1, -1, 1)
    predictor = GraspPredictor.from_pretrained(pretrained, mesh=mesh)
    made = cornell_examples(cornell, predictor.tokenizer, predictor.format_config, kinds)
    given = {"value_window": value_window, "angle_window": angle_window}
    windows = {name: int(described.get(name, 0)) if given[name] is None else given[name] for name in given}
    evaluation = GraspEvaluation(predictor.model_config, mesh, made.records, predictor.tokenizer,
                                 predictor.format_config, "honest", batch_size=batch_size,
                                 max_examples=max_examples, **windows)
    figures, rows = evaluation.results(predictor.params)
    label = f"cornell-{pathlib.Path(cornell).resolve().name}"
    config = predictor.format_config
    results = {"accuracy": figures.pop("accuracy"), "pretrained": str(pretrained.resolve()),
               "step": described["step"], "split": label, "cornell": str(pathlib.Path(cornell).resolve()),
               "kinds": list(kinds), "photos": made.photos, "views_without_grasps": made.views_without_grasps,
               "representation": config.representation, "individual": config.individual,
               "angle_code": config.angle_code, **figures, "max_examples": max_examples, "batch_size": batch_size,
               **windows, "seconds": round(time.perf_counter() - started, 2)}
    return results, rows, base / label
