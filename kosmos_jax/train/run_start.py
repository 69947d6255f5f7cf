"""Starting a KOSMOS-E run from another run's workdir (config.init_from = WORKDIR): fine-tuning from
a pretraining run (configs/pretrain.py).

The new run takes the parameters of the other run's checkpoint `config.init_step` (-1: its newest;
the optimiser state is not read), and builds its data with that run's tokenizer, so that every
token id means what it meant in pretraining. The model must be the other run's (same shapes,
vocabulary and connector); anything else is an error naming both. What was taken is recorded in
run.json ("init": the workdir and the step).
"""

from __future__ import annotations

import hashlib
import pathlib

from kosmos_jax.workdir.files import RUN_FILE, TOKENIZER_FILE, RunError


def is_run(init_from: str) -> bool:
    """Whether `init_from` names a training run's workdir (as opposed to a KOSMOS-2 folder)."""
    return bool(init_from) and (pathlib.Path(init_from) / RUN_FILE).is_file()


def _digest(path: pathlib.Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def use_run_tokenizer(config) -> None:
    """Point config.data.build at the tokenizer of the run config.init_from (in place). A build that
    already names a tokenizer must name a file with the same content, else ValueError."""
    tokenizer = pathlib.Path(config.init_from) / TOKENIZER_FILE
    if not tokenizer.is_file():
        raise RunError(f"{tokenizer} is missing: config.init_from={config.init_from} is a workdir without its tokenizer")
    build = config.data.build
    given = build.get("tokenizer")
    if given and _digest(pathlib.Path(given)) != _digest(tokenizer):
        raise ValueError(f"config.data.build.tokenizer={given} is not the tokenizer of config.init_from={config.init_from} "
                         f"({tokenizer}); a run fine-tuned from another must read its token ids: leave it unset")
    with build.unlocked():
        build.tokenizer = str(tokenizer)
        build.tokenizer_scheme = "native"


def run_params(config, model_config, mesh):
    """(step, parameters) of checkpoint config.init_step (-1: the newest) of the run config.init_from,
    placed on `mesh`; ValueError when that run's model is not `model_config`."""
    from kosmos_jax.workdir.run import open_run  # the run layer reads the dataset identity; imported on use

    run = open_run(config.init_from)
    if run.model_config.to_hf_dict() != model_config.to_hf_dict() or \
            run.model_config.connector_grid_code != model_config.connector_grid_code:
        raise ValueError(f"config.init_from={config.init_from} holds another model than this config's: "
                         f"{_difference(run.model_config, model_config)}; give this config the model of that run")
    step = config.get("init_step", -1)
    return run.params(None if step < 0 else step, mesh)


def _difference(stored, wanted) -> str:
    stored_dict, wanted_dict = _flat(stored.to_hf_dict()), _flat(wanted.to_hf_dict())
    stored_dict["connector_grid_code"], wanted_dict["connector_grid_code"] = (stored.connector_grid_code,
                                                                              wanted.connector_grid_code)
    differ = [f"{key} {stored_dict.get(key)} there, {wanted_dict.get(key)} here"
              for key in sorted(set(stored_dict) | set(wanted_dict)) if stored_dict.get(key) != wanted_dict.get(key)]
    return "; ".join(differ[:4])


def _flat(tree: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out
