"""Every arm of an experiment builds, without training: its model by jax.eval_shape, its optimiser, its
batch over this machine's devices (the mesh it names), and its data settings as the build (or the
baselines' fold views) would take them.

    reports = check_experiment(config)   # one dict per (arm, protocol, scheme); raises ExperimentError

Nothing is read or written: a KOSMOS-E arm's data section becomes a dataset.build.BuildConfig whose
text format and kinds are validated by their own code, with the source only named (a synthetic set
is not drawn). The model's vocabulary is the tokenizer's, which only a build knows: the shape
check takes KOSMOS-2's when the arm loads its tokenizer or weights, else `VOCAB_MARGIN` ids more
than the build's text pieces (a trained tokenizer's size is at most its pieces plus its symbols).
"""

from __future__ import annotations

import functools
import json

import jax

from kosmos_jax.baselines.family import BaselineConfig, make_family
from kosmos_jax.dataset.build import BuildConfig, check_validation
from kosmos_jax.dataset.samples import parse_kinds
from kosmos_jax.experiments import spec
from kosmos_jax.experiments.spec import ExperimentError
from kosmos_jax.models import config as model_configs
from kosmos_jax.models.kosmos2 import abstract_model, param_count
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.train.task import check_batch_layout
from kosmos_jax.workdir.model import model_config

VOCAB_MARGIN = 2048
SOURCES = ("synthetic", "cornell")  # or a Cornell-format folder's path
RECIPES = ("random", "paper")


def check_source(data, folds: int, where: str) -> str:
    if not isinstance(data.source, str) or not data.source:
        raise ExperimentError(f"{where}: data.source={data.source!r}: expected {' or '.join(SOURCES)} or a folder")
    if data.source == "synthetic" and data.synthetic_photos < folds:
        raise ExperimentError(f"{where}: {data.synthetic_photos} synthetic photos cannot make {folds} folds")
    return data.source


def check_fold(protocol, scheme, fold, folds, where: str, task: str) -> None:
    spec.parse_protocols(protocol, f"{where}: protocol", task)
    spec.parse_names(scheme, spec.SCHEMES, f"{where}: scheme")
    if not 0 <= fold < folds:
        raise ExperimentError(f"{where}: fold {fold} outside 0..{folds - 1}")


def build_settings(data, where: str) -> BuildConfig:
    """The arm's data.build as the build's own config, validated by the build's format and kinds code."""
    settings = data.build.to_dict()
    kinds = settings.pop("kinds")
    settings["kinds"] = tuple(k.strip() for k in kinds.split(",")) if isinstance(kinds, str) else kinds
    try:
        build = BuildConfig(source=str(data.source), out=None, **settings)
        build.format_config()
        parse_kinds(build.kinds or ("all",))
        check_validation(build)
    except (TypeError, ValueError) as error:
        raise ExperimentError(f"{where}: data.build: {error}") from None
    if build.augmentations < 1 or build.recipe not in RECIPES:
        raise ExperimentError(f"{where}: data.build: augmentations={build.augmentations}, recipe={build.recipe!r}: "
                              f"expected at least 1 and one of {RECIPES}")
    check_fold(build.protocol, build.split, build.fold, build.folds, where, "kosmos_e")
    return build


@functools.lru_cache(maxsize=None)
def kosmos_params(model_json: str, vocab_size: int) -> int:
    import ml_collections

    cfg = model_config(ml_collections.ConfigDict(json.loads(model_json)), vocab_size)
    return param_count(abstract_model(cfg))


def check_kosmos_e(config, where: str) -> dict:
    build = build_settings(config.data, where)
    check_source(config.data, build.folds, where)
    pretrained = bool(build.tokenizer or config.init_from)
    vocab = (model_configs.get_config(config.model.size).text.vocab_size if pretrained
             else build.text_pieces + VOCAB_MARGIN)
    try:
        params = kosmos_params(json.dumps(config.model.to_dict(), sort_keys=True), vocab)
        positions = model_config(config.model, vocab).text.max_position_embeddings
    except (KeyError, TypeError, ValueError) as error:
        raise ExperimentError(f"{where}: model: {error}") from None
    if build.max_length > positions:
        raise ExperimentError(f"{where}: data.build.max_length={build.max_length} exceeds the model's {positions} positions")
    return {"params": params, "vocab_size": vocab, "kinds": build.kinds, "representation": build.representation,
            "source": config.data.source}


@functools.lru_cache(maxsize=None)
def baseline_params(network: str, mode: str, channels: int, loss: str | None) -> int:
    family = make_family(BaselineConfig(network=network, mode=mode, channels=channels, loss=loss))
    _, params, _ = jax.eval_shape(lambda: family.init(0))
    return int(sum(x.size for x in jax.tree.leaves(params)))


def check_baseline(config, where: str) -> dict:
    data = config.data
    check_fold(data.protocol, data.scheme, data.fold, data.folds, where, "baseline")
    check_source(data, data.folds, where)
    if data.copies < 1 or data.recipe not in RECIPES:
        raise ExperimentError(f"{where}: data.copies={data.copies}, data.recipe={data.recipe!r}: expected at least 1 "
                              f"and one of {RECIPES}")
    model = config.model
    try:
        params = baseline_params(model.network, model.mode, model.channels, model.loss or None)
    except (TypeError, ValueError) as error:
        raise ExperimentError(f"{where}: model: {error}") from None
    return {"params": params, "network": model.network, "mode": model.mode, "source": data.source}


def check_run(config, where: str) -> dict:
    """Model, optimiser and data of one training config (a fold's)."""
    if config.train.steps < 1 or config.train.batch_size < 1:
        raise ExperimentError(f"{where}: train.steps={config.train.steps}, train.batch_size={config.train.batch_size}: "
                              "both must be positive")
    try:
        make_optimizer(config.optimizer, config.train.steps)
    except (TypeError, ValueError) as error:
        raise ExperimentError(f"{where}: optimizer: {error}") from None
    try:
        check_batch_layout(config, make_mesh(config.mesh.data, config.mesh.fsdp, config.mesh.tensor))
    except ValueError as error:
        raise ExperimentError(f"{where}: on this machine's {jax.device_count()} devices: {error}") from None
    task = spec.task_of(config)
    report = check_kosmos_e(config, where) if task == "kosmos_e" else check_baseline(config, where)
    return {"task": task, "steps": config.train.steps, "batch_size": config.train.batch_size, **report}


def check_experiment(config) -> list[dict]:
    """One report per (arm, protocol, scheme) of every arm, at the first chosen fold."""
    fold = spec.parse_folds(config.folds, config.k)[0]
    reports = []
    for run in spec.runs(config, every=True):
        if run.fold != fold:
            continue
        arm = spec.arm_config(config, run.arm)
        fold_run = spec.Run(run.arm, run.protocol, run.scheme, fold)
        reports.append({"arm": run.arm, "protocol": run.protocol, "scheme": run.scheme,
                        **check_run(spec.fold_config(arm, fold_run, config.k), fold_run.name)})
    return reports
