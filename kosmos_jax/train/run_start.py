"""Starting a KOSMOS-E run from another run (config.init_from = its WORKDIR, or the FOLDER that
`python -m kosmos_jax.workdir.export` made of it): fine-tuning from a pretraining run (configs/pretrain.py).

The new run takes the parameters of the other run's checkpoint `config.init_step` (-1: its newest;
the optimiser state is not read) or of the exported folder, and builds its data with that run's
tokenizer (and, for a folder, the id scheme and number mode its kosmos_e.json records), so that
every token id means what it meant in pretraining. The model must be the other run's (same shapes,
vocabulary and connector); anything else is an error naming both. One difference can be asked for:
with config.init_resample_positions, a vision tower of another image_size (the same patch_size) starts
from the other's weights with its position embeddings resampled to the new grid (a finer grid of
patches for the same view, as ViTs are fine-tuned at a higher resolution). What was taken is recorded in
run.json ("init": the workdir or folder, and the step).
"""

from __future__ import annotations

import dataclasses
import hashlib
import pathlib

import jax

from flax import nnx

from kosmos_jax.models import patch_grid, weights
from kosmos_jax.models.config import EXTENSION_FIELDS
from kosmos_jax.workdir.files import RUN_FILE, TOKENIZER_FILE, RunError
from kosmos_jax.workdir.pretrained import FORMAT_FILE, read_description


def is_run(init_from: str) -> bool:
    """Whether `init_from` names a training run's workdir (as opposed to a KOSMOS-2 folder)."""
    return bool(init_from) and (pathlib.Path(init_from) / RUN_FILE).is_file()


def is_export(init_from: str) -> bool:
    """Whether `init_from` names a folder exported from a run (kosmos_e.json beside its weights)."""
    return bool(init_from) and (pathlib.Path(init_from) / FORMAT_FILE).is_file()


def is_start(init_from: str) -> bool:
    """A run to start from, as a workdir or as its export (not KOSMOS-2's own folder)."""
    return is_run(init_from) or is_export(init_from)


def _digest(path: pathlib.Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def use_run_tokenizer(config) -> None:
    """Point config.data.build at the tokenizer of the run (or export) config.init_from, in place. A
    build that already names a tokenizer must name a file with the same content, and a folder's
    number mode must be the build's, else ValueError."""
    tokenizer = pathlib.Path(config.init_from) / TOKENIZER_FILE
    what = "an exported folder" if is_export(config.init_from) else "a workdir"
    if not tokenizer.is_file():
        raise RunError(f"{tokenizer} is missing: config.init_from={config.init_from} is {what} without its tokenizer")
    build = config.data.build
    given = build.get("tokenizer")
    if given and _digest(pathlib.Path(given)) != _digest(tokenizer):
        raise ValueError(f"config.data.build.tokenizer={given} is not the tokenizer of config.init_from={config.init_from} "
                         f"({tokenizer}); a run fine-tuned from another must read its token ids: leave it unset")
    scheme = "native"
    if is_export(config.init_from):
        recorded = read_description(config.init_from)["tokenizer"]
        scheme = recorded["scheme"]
        if recorded["numbers"] != build.numbers:
            raise ValueError(f"config.init_from={config.init_from} wrote its numbers as {recorded['numbers']!r} "
                             f"tokens, this config as {build.numbers!r}: give --config.data.build.numbers="
                             f"{recorded['numbers']}")
    with build.unlocked():
        build.tokenizer = str(tokenizer)
        build.tokenizer_scheme = scheme


def start_params(config, model_config, mesh):
    """(step, parameters) that a run starting from config.init_from (a workdir or its export) takes: checkpoint
    config.init_step of a workdir (-1: its newest), placed on `mesh`; ValueError, before any weight is read, when
    the model differs or a folder is asked for a step. With config.init_resample_positions the start's tower may
    have another image_size (the same patch_size): its position embeddings are resampled to this config's grid."""
    resample = bool(config.get("init_resample_positions", False))
    wanted_step = config.get("init_step", -1)
    if is_run(config.init_from):
        from kosmos_jax.workdir.run import open_run  # the run layer reads the dataset identity; imported on use

        run = open_run(config.init_from)
        stored = run.model_config
        check_same_model(stored, model_config, config.init_from, resample)
        step, params = run.params(None if wanted_step < 0 else wanted_step, mesh)
    else:
        if wanted_step >= 0:
            raise ValueError(f"config.init_from={config.init_from} is an exported folder: it holds one step's "
                             "weights; config.init_step picks a checkpoint of a workdir only")
        stored = weights.read_config(config.init_from)
        check_same_model(stored, model_config, config.init_from, resample)
        model = weights.load_pretrained(config.init_from, seed=config.train.seed, compute_dtype=model_config.compute_dtype,
                                        remat=model_config.remat, scan_layers=model_config.scan_layers)
        step, params = int(read_description(config.init_from)["step"]), nnx.state(model, nnx.Param)
    if stored.vision.image_size != model_config.vision.image_size:
        params = with_resampled_positions(params, model_config.vision.image_size // model_config.vision.patch_size)
    return step, params


def with_resampled_positions(params, side: int):
    """`params` (an nnx.State of the model, changed in place) with the vision tower's position embeddings resampled to a side x side
    grid (patch_grid.resample_positions), placed as the old table was (a loaded folder's arrays are not committed to
    a device, and the new one must not be either: jit places them all on the mesh)."""
    table = next(variable for path, variable in nnx.to_flat_state(params) if weights.hf_key(path) == weights.VISION_POSITIONS)
    old = table.get_value()
    new = patch_grid.resample_positions(old, side)
    table.set_value(jax.device_put(new, old.sharding) if old.committed else new)
    return params


def check_same_model(loaded_config, model_config, init_from, resample_positions: bool = False) -> None:
    """ValueError naming the difference when a loaded model is not `model_config`; with `resample_positions` a
    vision tower that differs only in image_size (whose position embeddings can be resampled) passes."""
    resized = loaded_config.replace(vision=dataclasses.replace(loaded_config.vision, image_size=model_config.vision.image_size))
    if _same(resized if resample_positions else loaded_config, model_config):
        return
    hint = "" if resample_positions or not _same(resized, model_config) else \
        " (only its image_size differs: --config.init_resample_positions=True resamples its position embeddings)"
    raise ValueError(f"config.init_from={init_from} holds another model than this config's: "
                     f"{_difference(loaded_config, model_config)}; give this config the model of that run{hint}")


def _same(loaded_config, model_config) -> bool:
    return loaded_config.to_hf_dict() == model_config.to_hf_dict() and \
        all(getattr(loaded_config, name) == getattr(model_config, name) for name in EXTENSION_FIELDS)


def _difference(stored, wanted) -> str:
    stored_dict, wanted_dict = flat(stored.to_hf_dict()), flat(wanted.to_hf_dict())
    for name in EXTENSION_FIELDS:
        stored_dict[name], wanted_dict[name] = getattr(stored, name), getattr(wanted, name)
    differ = [f"{key} {stored_dict.get(key)} there, {wanted_dict.get(key)} here"
              for key in sorted(set(stored_dict) | set(wanted_dict)) if stored_dict.get(key) != wanted_dict.get(key)]
    return "; ".join(differ[:4])


def flat(tree: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out
