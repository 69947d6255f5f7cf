"""A trained KOSMOS-E run's workdir as the evaluation needs it: its model, text format, protocol,
tokenizer, test data and the parameters of one checkpoint; and what any run's workdir holds (run.json,
its task, its checkpoint steps), which the baselines' evaluation (baseline_run) reads too.

Everything is read back from what the trainer wrote: run.json (the config, the data identity with
the FormatConfig the examples were made with, the dataset folder), tokenizer.model and
checkpoints/STEP. Errors name the file that is missing and what to do.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import ml_collections

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.text.tokenizer import Tokenizer, load_tokenizer
from kosmos_jax.train.checkpoint import Checkpoints
from kosmos_jax.train.data import open_dataset
from kosmos_jax.train.mesh import make_mesh
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.train.state import abstract_train_state
from kosmos_jax.train.trainer import RUN_FILE, TOKENIZER_FILE, model_config


class RunError(FileNotFoundError):
    """The workdir lacks what an evaluation needs."""


@dataclasses.dataclass(frozen=True)
class Run:
    workdir: pathlib.Path
    config: ml_collections.ConfigDict
    description: dict  # run.json
    tokenizer: Tokenizer
    model_config: Kosmos2Config
    format_config: FormatConfig

    @property
    def protocol(self) -> str:
        return self.description["data_identity"]["build"]["protocol"]

    def steps(self) -> list[int]:
        return checkpoint_steps(self.workdir)

    def split(self, name: str):
        """The stored split `name` of the run's dataset (StoredSplit)."""
        folder = pathlib.Path(self.description["dataset_dir"])
        if not folder.is_dir():
            raise RunError(f"the run's dataset {folder} (run.json dataset_dir) is gone; rebuild it with the run's "
                           "config (python -m kosmos_jax.dataset.build) or evaluate on photos with --cornell")
        splits = open_dataset(folder).splits()
        if name not in splits:
            raise ValueError(f"unknown split {name!r}; the dataset {folder} has {sorted(splits)}")
        return splits[name]

    def params(self, step: int | None, mesh=None):
        """(step, parameters) of checkpoint `step` (None: the newest), placed on `mesh` (default: all
        devices on the fsdp axis)."""
        step = chosen_step(self.workdir, step)
        mesh = mesh or make_mesh(1, -1, 1)
        tx, _ = make_optimizer(self.config.optimizer, self.config.train.steps)
        checkpoints = Checkpoints(self.workdir, asynchronous=False)
        try:
            state, _, _ = checkpoints.restore(step, abstract_train_state(self.model_config, tx, mesh))
        finally:
            checkpoints.close()
        return step, state.params


def checkpoint_steps(workdir: pathlib.Path) -> list[int]:
    if not (workdir / "checkpoints").is_dir():
        return []
    checkpoints = Checkpoints(workdir, asynchronous=False)
    try:
        return sorted(checkpoints.all_steps())
    finally:
        checkpoints.close()


def chosen_step(workdir: pathlib.Path, step: int | None) -> int:
    """`step` (None: the newest) if the workdir holds its checkpoint, else a RunError saying what it holds."""
    steps = checkpoint_steps(workdir)
    if not steps:
        raise RunError(f"{workdir} holds no checkpoint (checkpoints/ is empty or missing): train first")
    step = steps[-1] if step is None else step
    if step not in steps:
        raise RunError(f"{workdir} has no checkpoint of step {step}; it has {steps}")
    return step


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


def open_run(workdir) -> Run:
    """A KOSMOS-E run's workdir (config.task "kosmos_e")."""
    workdir = pathlib.Path(workdir)
    description = read_description(workdir)
    if run_task(description) != "kosmos_e":
        raise RunError(f"{workdir} holds a {run_task(description)!r} run, not KOSMOS-E's")
    tokenizer_path = workdir / TOKENIZER_FILE
    if not tokenizer_path.is_file():
        raise RunError(f"{tokenizer_path} is missing: the trainer copies the dataset's tokenizer there; copy it back "
                       f"from the dataset folder ({description.get('dataset_dir')}/tokenizer.model)")
    build = description["data_identity"]["build"]
    scheme = "native" if build.get("tokenizer") is None else "fairseq"  # as the build chose it
    tokenizer = load_tokenizer(tokenizer_path, scheme=scheme, numbers=build["numbers"])
    config = ml_collections.ConfigDict(description["config"])
    model = model_config(config.model, tokenizer.vocab_size)
    if json.loads(json.dumps(model.to_hf_dict())) != description["model"]:
        raise RunError(f"{workdir}/{RUN_FILE}: its config's model and tokenizer do not give its stored model")
    return Run(workdir, config, description, tokenizer, model,
               FormatConfig(**description["data_identity"]["format"]))
