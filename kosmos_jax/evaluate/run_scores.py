"""A trained run's scores, by what it trained (run.json's config.task): KOSMOS-E's answers decoded
with and without the grasp grammar, or a baseline's predicted grasps (baseline_run.py); and the
files the evaluate command writes of them.

    results, rows, folder = evaluate("runs/demo", step=None, split="test")
    results, rows, folder = evaluate("runs/demo", cornell="photos/", kinds=("non", "single"))
    write(results, rows, folder)        # folder/results.json, results.md, answers.jsonl

`python -m kosmos_jax.evaluate` (__main__.py) is this with its flags parsed; the demo and the
experiment runner call it directly.
"""

from __future__ import annotations

import json
import os
import pathlib
import time
from collections.abc import Sequence

from kosmos_jax.instruct.kinds import NON
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_decoding import chosen_windows, configured_windows
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.scoring.tally import markdown
from kosmos_jax.workdir.files import read_description, run_task
from kosmos_jax.workdir.run import open_run

Scored = tuple[dict, list[dict], pathlib.Path]  # results, one row per example, the folder they belong in


def evaluate(workdir: str | os.PathLike, *, step: int | None = None, split: str = "test",
             cornell: str | os.PathLike | None = None, kinds: Sequence[str] = (NON,), batch_size: int = 16,
             max_examples: int = 0, value_window: int | None = None, angle_window: int | None = None,
             unconstrained: bool = True, mosaic_zoom: bool = False) -> Scored:
    """The run in `workdir` scored at checkpoint `step` (None: the newest) on `split` of its data, or
    with `cornell` on every photo of that Cornell-format folder, asked the instruction `kinds`.
    `max_examples` decodes the first N examples (0: all). `value_window`: how coordinate value tokens
    are read (`models.value_decoding`; 0: greedy; None: as the run's config says); `angle_window`: how
    angle tokens are (0: the mode; None: as the run's config says). `unconstrained` False: a KOSMOS-E
    run's answers are decoded with the grammar only (GraspEvaluation.results). `mosaic_zoom` True: a
    KOSMOS-E run's mosaic instructions are also answered again on the quadrant their first answer chose
    (scoring.zoom), results' "mosaic_zoom" figures beside the one-pass ones."""
    if batch_size < 1 or max_examples < 0:
        raise ValueError("batch_size must be positive and max_examples at least 0")
    settings = dict(step=step, split=split, cornell=cornell, kinds=tuple(kinds), batch_size=batch_size,
                    max_examples=max_examples)
    if run_task(read_description(workdir)) == "baseline":
        # imported here: a baseline's views are remade with the trainer's code (train.baseline_task),
        # which scoring KOSMOS-E's runs does not import
        from kosmos_jax.evaluate.baseline_run import evaluate_baseline

        return evaluate_baseline(workdir, **settings)
    return evaluate_kosmos_e(workdir, **settings, value_window=value_window, angle_window=angle_window,
                             unconstrained=unconstrained, mosaic_zoom=mosaic_zoom)


def evaluate_kosmos_e(workdir, *, step: int | None, split: str, cornell, kinds: tuple[str, ...], batch_size: int,
                      max_examples: int, value_window: int | None = None, angle_window: int | None = None,
                      unconstrained: bool = True, mosaic_zoom: bool = False) -> Scored:
    """evaluate() on a KOSMOS-E run."""
    started = time.perf_counter()
    run = open_run(workdir)
    mesh = make_mesh(1, -1, 1)
    step, params = run.params(step, mesh)
    if cornell:
        made = cornell_examples(cornell, run.tokenizer, run.format_config, kinds)
        examples, label, protocol = made.records, f"cornell-{pathlib.Path(cornell).resolve().name}", "honest"
        source = {"cornell": str(pathlib.Path(cornell).resolve()), "kinds": list(kinds), "photos": made.photos,
                  "views_without_grasps": made.views_without_grasps}
    else:
        examples, label, protocol = run.split(split), split, run.protocol
        source = {"dataset_dir": run.description["dataset_dir"]}
    windows = chosen_windows(configured_windows(run.config), value_window=value_window, angle_window=angle_window)
    evaluation = GraspEvaluation(run.model_config, mesh, examples, run.tokenizer, run.format_config, protocol,
                                 batch_size=batch_size, max_examples=max_examples, **windows)
    figures, rows = evaluation.results(params, unconstrained=unconstrained, mosaic_zoom=mosaic_zoom)
    results = {"accuracy": figures.pop("accuracy"), "workdir": str(run.workdir.resolve()), "step": step,
               "split": label, **source, "representation": run.format_config.representation,
               "individual": run.format_config.individual, "angle_code": run.format_config.angle_code, **figures,
               "max_examples": max_examples, "batch_size": batch_size, **windows,
               "seconds": round(time.perf_counter() - started, 2)}
    folder = run.workdir / "eval" / str(step)
    return results, rows, folder if label == "test" else folder / label


def write(results: dict, rows: list[dict], folder: pathlib.Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (folder / "results.md").write_text(markdown(results))
    (folder / "answers.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
