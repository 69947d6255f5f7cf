"""The files a trainer writes in a workdir besides its checkpoints, and its description (run.json)."""

from __future__ import annotations

import json
import pathlib

RUN_FILE = "run.json"  # the config, the data identity, the dataset folder and the model (trainer.run_description)
TOKENIZER_FILE = "tokenizer.model"  # KOSMOS-E runs: the dataset's tokenizer, copied


class RunError(FileNotFoundError):
    """The workdir lacks what a reader needs."""


class RunMismatchError(ValueError):
    """The workdir holds a run of another model or dataset than the config asks for."""


def read_description(workdir) -> dict:
    """The run.json a trainer wrote in `workdir`."""
    workdir = pathlib.Path(workdir)
    if not (workdir / RUN_FILE).is_file():
        raise RunError(f"{workdir} is not a training run's workdir (no {RUN_FILE}); "
                       "train one with python -m kosmos_jax.train --config=... --workdir=...")
    return json.loads((workdir / RUN_FILE).read_text())


def run_task(description: dict) -> str:
    """What the run trained (its config.task): "kosmos_e" or "baseline"."""
    return description["config"].get("task", "kosmos_e")
