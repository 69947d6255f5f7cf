"""A KOSMOS-E run's parameters as a KOSMOS-2 folder in transformers' layout.

    export_pretrained("runs/demo", "exported/demo")           # the newest checkpoint
    GraspPredictor.from_pretrained("exported/demo", "exported/demo/tokenizer.model", scheme="native", ...)

Writes config.json and model.safetensors (models.weights.save_pretrained) from the parameters of
one checkpoint (restored alone, on one device), and the run's tokenizer.model beside them.
"""

from __future__ import annotations

import pathlib
import shutil

import jax
from flax import nnx

from kosmos_jax.models import weights
from kosmos_jax.models.kosmos2 import abstract_model, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.scoring.decoding import fixed_streams
from kosmos_jax.workdir.files import TOKENIZER_FILE
from kosmos_jax.workdir.run import open_run


def export_pretrained(workdir, folder, step: int | None = None, max_shard_bytes: int | None = None) -> int:
    """Write checkpoint `step` (None: the newest) of the run in `workdir` to `folder`; returns the step."""
    run = open_run(workdir)
    step, params = run.params(step, make_mesh(1, 1, 1, devices=jax.devices()[:1]))
    graphdef, _, rest = split_model(abstract_model(run.model_config))
    folder = weights.save_pretrained(nnx.merge(graphdef, params, fixed_streams(rest)), folder, max_shard_bytes)
    shutil.copyfile(run.workdir / TOKENIZER_FILE, pathlib.Path(folder) / TOKENIZER_FILE)
    return step
