"""A KOSMOS-E run's workdir opened: its config, description (run.json), tokenizer, model, text
format and protocol, its dataset's splits, and the parameters of one checkpoint.

Everything is read back from what the trainer wrote: run.json (the config, the data identity with
the FormatConfig the examples were made with, the dataset folder), tokenizer.model and
checkpoints/STEP, of which only the parameters are read. Errors name the file that is missing and
what to do.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import jax
import ml_collections
from jax.sharding import Mesh, NamedSharding

from kosmos_jax.dataset.built import open_dataset
from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.kosmos2 import abstract_model, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.sharding import param_shardings
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.text.tokenizer import Tokenizer, load_tokenizer
from kosmos_jax.workdir.checkpoints import checkpoint_steps, chosen_step, restore_params
from kosmos_jax.workdir.files import RUN_FILE, TOKENIZER_FILE, RunError, read_description, run_task
from kosmos_jax.workdir.model import model_config


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

    def params(self, step: int | None, mesh: Mesh | None = None):
        """(step, parameters) of checkpoint `step` (None: the newest), placed on `mesh` (default: all
        devices on the fsdp axis); the checkpoint's optimiser state is not read."""
        step = chosen_step(self.workdir, step)
        return step, restore_params(self.workdir, step, abstract_params(self.model_config, mesh or make_mesh(1, -1, 1)))


def abstract_params(config: Kosmos2Config, mesh: Mesh):
    """The model's parameters as ShapeDtypeStructs carrying their shardings on `mesh` (a restore target)."""
    _, params, _ = split_model(abstract_model(config))

    def with_sharding(sharding, variable):
        return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), variable)

    return jax.tree.map(with_sharding, param_shardings(params, mesh), params,
                        is_leaf=lambda x: isinstance(x, NamedSharding))


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
    scheme = "native" if build.get("tokenizer") is None else build.get("tokenizer_scheme", "fairseq")  # as the build chose it
    tokenizer = load_tokenizer(tokenizer_path, scheme=scheme, numbers=build["numbers"])
    config = ml_collections.ConfigDict(description["config"])
    model = model_config(config.model, tokenizer.vocab_size)
    if json.loads(json.dumps(model.to_hf_dict())) != description["model"]:
        raise RunError(f"{workdir}/{RUN_FILE}: its config's model and tokenizer do not give its stored model")
    return Run(workdir, config, description, tokenizer, model,
               FormatConfig(**description["data_identity"]["format"]))
