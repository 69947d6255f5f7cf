"""An experiment config and the runs it asks for: (arm, protocol, scheme, fold), each with its training config.

An experiment config (configs/experiments/*.py, made with `experiment` and `arm` below) holds:
  name        the experiment ("table1")
  arms        {arm name: arm(...)}: a training config file and variant ("configs/kosmos_e.py:demo",
              "configs/baselines.py:ggcnn2_d"), dotted overrides, a `series` (the line of the
              data-size plot it belongs to; "" = none) and the arm's `protocols` ("" = the experiment's;
              else those of the experiment's it is scored under)
  run_arms    "" (every arm) or "kosmos_e,ggcnn2_d": the arms this invocation trains
  schemes     "image", "object" or "image,object": image-wise and/or object-wise folds
  protocols   some of "honest", "paper" (DESIGN.md section 3) and "public" (the baselines' own protocol,
              kosmos_jax.baselines: one split, so fold 0 of each scheme only; baseline arms only)
  k           folds of the cross-validation
  folds       "" (all k) or "0,1": the folds this invocation trains (a SLURM array task runs one)
  init_from   a KOSMOS-2 folder every KOSMOS-E arm starts from ("" = the arm's own config.init_from);
              its sentencepiece.bpe.model becomes the arm's tokenizer unless the arm names one
  data_size_plot  write WORKDIR/data_size.png and data_size.json (Fig. 6)

A training config's fold settings are set per run: KOSMOS-E's data.build.{protocol, split, fold,
folds}, a baseline's (config.task "baseline") data.{protocol, scheme, fold, folds}.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import importlib.util
import json
import pathlib

import ml_collections

from kosmos_jax.sources import splits

REPO = pathlib.Path(__file__).resolve().parents[2]
SCHEMES = ("image", "object")
PROTOCOLS = splits.PROTOCOLS
TASKS = ("kosmos_e", "baseline")
FOLD_FIELDS = {  # task -> (protocol, scheme, fold, folds) fields of its training config
    "kosmos_e": ("data.build.protocol", "data.build.split", "data.build.fold", "data.build.folds"),
    "baseline": ("data.protocol", "data.scheme", "data.fold", "data.folds"),
}
KOSMOS_TOKENIZER = "sentencepiece.bpe.model"  # the tokenizer file of a KOSMOS-2 folder
# the committed pretrained start that the pretrained arms (and make demo until 2026-11-30) fine-tune (results/pretrain/README.md),
# relative to the repository root, where the demo and the runner are started
SHIPPED_START = "results/pretrain/demo_photos1200"
# the committed grounding start that the experiments' grounded arms fine-tune (configs/kosmos_e.py:demo_grounded),
# and make demo until 2026-12-06: pretrained on scenes made on the fly for 6,000 steps, then 4,000 more twice, its
# connector reads the instruction (results/pretrain/README.md)
GROUNDING_START = "results/pretrain/grounding14000"
# grounding21200 continued for 2,400 steps at a peak rate of 2e-4 on the same chunks of scenes: make demo's start
# since 2026-12-07's evening (configs/kosmos_e.py:demo_grounded224_consensus, results/finer_grid/README.md)
DEMO_START = "results/pretrain/grounding23600_lr2e-4"
# that start continued for 7,200 steps on a 16 x 16 grid of patches (224 px views, its position embeddings
# resampled at the first step), in four runs each from the last one's export: make demo's start on 2026-12-07
GROUNDING21200_START = "results/pretrain/grounding21200"
# the first 2,400 of those steps: make demo's start on 2026-12-06
GROUNDING16400_START = "results/pretrain/grounding16400"
# the same start 4,000 steps earlier: make demo's start on 2026-12-01 (results/demo/grounded10000)
GROUNDING10000_START = "results/pretrain/grounding10000"
# the same run at its 6,000th step: make demo's start from 2026-11-30 to 2026-12-01, Table II's cpu_grounded arms
GROUNDING6000_START = "results/pretrain/grounding6000"


class ExperimentError(ValueError):
    """An experiment config that cannot be run as it is (unknown arm, bad fold list, missing file...)."""


def nested(dotted: dict) -> dict:
    """{"data.build.kinds": "non"} -> {"data": {"build": {"kinds": "non"}}}."""
    out: dict = {}
    for key, value in dotted.items():
        *parents, leaf = key.split(".")
        target = out
        for part in parents:
            target = target.setdefault(part, {})
            if not isinstance(target, dict):
                raise ExperimentError(f"override {key!r} goes inside {part!r}, which another override sets to a value")
        target[leaf] = value
    return out


def dotted(tree, prefix: str = "") -> dict:
    """The leaves of a nested dict or ConfigDict as {"a.b.c": value}."""
    items = tree.items() if isinstance(tree, (dict, ml_collections.ConfigDict)) else ()
    out = {}
    for key, value in items:
        path = f"{prefix}{key}"
        if isinstance(value, (dict, ml_collections.ConfigDict)) and len(value):
            out.update(dotted(value, path + "."))
        else:
            out[path] = value
    return out


def arm(config: str, overrides: dict | None = None, series: str = "", protocols: str = "") -> ml_collections.ConfigDict:
    """One arm: `config` is FILE:VARIANT of a training config, `overrides` {dotted field: value},
    `protocols` "" (every protocol the experiment runs) or the ones this arm is scored under."""
    return ml_collections.ConfigDict(dict(config=config, overrides=nested(overrides or {}), series=series,
                                          protocols=protocols))


def experiment(name: str, arms: dict, *, schemes: str, protocols: str, k: int = 5, folds: str = "",
               data_size_plot: bool = False) -> ml_collections.ConfigDict:
    config = ml_collections.ConfigDict()
    config.name = name
    config.arms = ml_collections.ConfigDict(arms)
    for order, name in enumerate(arms):  # a ConfigDict sorts its keys: keep the config's order for tables
        config.arms[name].order = order
    config.run_arms = ""
    config.schemes = schemes
    config.protocols = protocols
    config.k = k
    config.folds = folds
    config.init_from = ""
    config.data_size_plot = data_size_plot
    return config

# -- lists given as text ------------------------------------------------------------------------


def parse_names(text, allowed, what: str) -> list[str]:
    """"a,b" -> ["a", "b"], each one of `allowed`; "" is an error (nothing chosen)."""
    names = [n.strip() for n in str(text).split(",")]
    if not text or any(not n for n in names):
        raise ExperimentError(f"{what} {text!r}: expected a comma-separated list of {', '.join(allowed)}")
    unknown = [n for n in names if n not in allowed]
    if unknown:
        raise ExperimentError(f"unknown {what} {', '.join(map(repr, unknown))}; expected some of {', '.join(allowed)}")
    return list(dict.fromkeys(names))


def parse_protocols(text, what: str = "protocol", task: str = "baseline") -> list[str]:
    """parse_names over PROTOCOLS; for a KOSMOS-E task "public", the baselines' one-split protocol,
    refused with why."""
    if task == "kosmos_e" and splits.PUBLIC in [n.strip() for n in str(text).split(",")]:
        raise ExperimentError(f"{what} {text!r}: {splits.PUBLIC_REFUSED}")
    return parse_names(text, PROTOCOLS, what)


def arm_protocols(config, name: str) -> list[str]:
    """The protocols arm `name` is scored under in this experiment: its own list, or the experiment's.
    An arm's list must lie within the experiment's (a typo would otherwise drop the arm silently)."""
    chosen = parse_protocols(config.protocols)
    own = config.arms[name].get("protocols", "")
    if not own:
        return chosen
    listed = parse_protocols(own, f"arm {name!r}: protocols")
    outside = [p for p in listed if p not in chosen]
    if outside:
        raise ExperimentError(f"arm {name!r} names protocol {outside[0]!r}, which the experiment does not run "
                              f"(protocols {config.protocols!r})")
    return listed


def protocol_folds(protocol: str, folds: list[int]) -> list[int]:
    """The folds a protocol has among `folds`: "public" is one split, fold 0 only."""
    return [f for f in folds if f == 0] if protocol == splits.PUBLIC else folds


def parse_folds(text, k: int) -> list[int]:
    """"" -> every fold of k; "0,2" -> [0, 2]; a fold outside 0..k-1, a repeat or a non-number is an error."""
    if not isinstance(k, int) or k < 2:
        raise ExperimentError(f"k={k!r}: cross-validation needs at least 2 folds")
    if isinstance(text, int) and not isinstance(text, bool):
        text = str(text)
    if not isinstance(text, str):
        raise ExperimentError(f"folds={text!r}: expected text such as '0,1' ('' = all {k})")
    if not text.strip():
        return list(range(k))
    parts = [p.strip() for p in text.split(",")]
    if not all(p.isdigit() for p in parts):
        raise ExperimentError(f"folds={text!r}: expected fold numbers separated by commas, such as '0,1'")
    folds = [int(p) for p in parts]
    outside = [f for f in folds if f >= k]
    if outside:
        raise ExperimentError(f"folds={text!r}: fold {outside[0]} does not exist with k={k} (folds 0..{k - 1})")
    if len(set(folds)) != len(folds):
        raise ExperimentError(f"folds={text!r} names a fold twice")
    return sorted(folds)


def arm_names(config) -> list[str]:
    """The arms in the order the config lists them."""
    names = sorted(config.arms.keys(), key=lambda name: config.arms[name].get("order", len(config.arms)))
    if not names:
        raise ExperimentError(f"experiment {config.name!r} has no arms")
    for name in names:
        if not name or "/" in name or name.startswith("."):
            raise ExperimentError(f"arm name {name!r} cannot name a folder")
    return names


def chosen_arms(config) -> list[str]:
    names = arm_names(config)
    return names if not config.run_arms else parse_names(config.run_arms, names, "arm")

# -- training configs ---------------------------------------------------------------------------


def config_path(path: str) -> pathlib.Path:
    """A config file as given (relative to the working directory), else relative to the repository."""
    given = pathlib.Path(path)
    for candidate in (given, REPO / given):
        if candidate.is_file():
            return candidate
    raise ExperimentError(f"config file {path!r} does not exist (looked in {pathlib.Path.cwd()} and {REPO})")


def config_module(path: str):
    """A config file as a module (config files are not a package), found as config_path finds it."""
    file = config_path(path)
    module_spec = importlib.util.spec_from_file_location(f"_config_{file.stem}", file)
    module = importlib.util.module_from_spec(module_spec)
    module_spec.loader.exec_module(module)
    return module


def load_config(spec: str) -> ml_collections.ConfigDict:
    """A training config from "FILE[:VARIANT]", as config_flags reads it: the file's get_config(VARIANT)."""
    path, _, variant = spec.partition(":")
    module = config_module(path)
    if not hasattr(module, "get_config"):
        raise ExperimentError(f"{module.__file__} has no get_config()")
    return module.get_config(variant or None)


def task_of(config) -> str:
    task = config.get("task", "kosmos_e")
    if task not in TASKS:
        raise ExperimentError(f"config.task={task!r}: the runner trains {', '.join(TASKS)}")
    return task


def set_field(config, key: str, value, where: str) -> None:
    *parents, leaf = key.split(".")
    target = config
    for depth, part in enumerate(parents):
        if not isinstance(target, ml_collections.ConfigDict) or part not in target:
            raise ExperimentError(f"{where}: the training config has no field {'.'.join(parents[:depth + 1])!r}")
        target = target[part]
    if not isinstance(target, ml_collections.ConfigDict) or leaf not in target:
        raise ExperimentError(f"{where}: the training config has no field {key!r}")
    try:
        target[leaf] = value
    except (TypeError, ValueError) as error:
        raise ExperimentError(f"{where}: {key}={value!r}: {error}") from None


@dataclasses.dataclass(frozen=True)
class Run:
    """One (arm, protocol, scheme, fold) of an experiment."""

    arm: str
    protocol: str
    scheme: str
    fold: int

    @property
    def name(self) -> str:
        return f"{self.arm} {self.protocol}-{self.scheme} fold {self.fold}"

    def workdir(self, root) -> pathlib.Path:
        return pathlib.Path(root) / self.arm / f"{self.protocol}-{self.scheme}-fold{self.fold}"


def arm_config(config, name: str) -> ml_collections.ConfigDict:
    """The arm's training config with its overrides and the experiment's init_from applied (no fold yet)."""
    if name not in config.arms:
        raise ExperimentError(f"unknown arm {name!r}; the experiment has {', '.join(config.arms.keys())}")
    entry = config.arms[name]
    try:
        base = load_config(entry.config)
    except ExperimentError as error:
        raise ExperimentError(f"arm {name!r}: {error}") from None
    except ValueError as error:  # the config file's own refusal (an unknown variant)
        raise ExperimentError(f"arm {name!r} ({entry.config}): {error}") from None
    for key, value in dotted(entry.overrides).items():
        set_field(base, key, value, f"arm {name!r} override")
    if task_of(base) == "kosmos_e" and config.init_from:
        base.init_from = str(config.init_from)
        tokenizer = pathlib.Path(config.init_from) / KOSMOS_TOKENIZER
        if base.data.build.tokenizer is None and tokenizer.is_file():
            base.data.build.tokenizer = str(tokenizer)
    return base


def fold_config(base, run: Run, k: int) -> ml_collections.ConfigDict:
    """A copy of an arm's config trained on `run`'s fold."""
    config = copy.deepcopy(base)
    for key, value in zip(FOLD_FIELDS[task_of(config)], (run.protocol, run.scheme, run.fold, k)):
        set_field(config, key, value, f"{run.name}: fold settings")
    return config


# Config fields added after fold records kept their recipe: left out of the fingerprint at the value
# that trains as before, so the records made before them still match
ADDED_AT = {"init_step": -1, "data.build.tokenizer_scheme": "fairseq", "data.stream.photos": 0,
            "data.stream.seed": 10_000, "train.pointing_target": "cell",
            "train.tower_offset_loss": 0.0, "train.slot_offset_loss": 0.0, "decode.value_window": 0,
            "decode.angle_window": 0, "train.phrase_patch_loss": 0.0,
            "train.tower_category_loss": 0.0, "train.tower_colour_loss": 0.0, "data.stream.kinds": "",
            "model.connector_instruction": False,
            "train.answer_pointing_loss": 0.0, "data.validation_fraction": 0.0,
            "data.stream.examples": 0, "train.grasp_eval_at_end": True,
            "model.remat_policy": "full", "model.dropout_mask_bits": 32, "init_resample_positions": False,
            "data.kind_repeats": "", "data.stream.targets": ""}


def recipe(fold_config) -> str:
    """A fingerprint of a fold's resolved training config, init_from left out (a path on one machine).
    A fold's record keeps it: a record of the same arm name and overrides, made before the arm's config
    file changed (a new default of its variant), has another."""
    leaves = {key: value for key, value in dotted(fold_config).items()
              if key != "init_from" and not (key in ADDED_AT and value == ADDED_AT[key])}
    return hashlib.sha256(json.dumps(leaves, sort_keys=True, default=str).encode()).hexdigest()[:16]


def check_recipe(record: dict, fold_config, where) -> None:
    """Refuse a fold's record made with another recipe than `fold_config`'s. Records made before
    recipes were recorded (2026-11-26) carry none and cannot be checked."""
    made = record.get("recipe")
    if made is not None and made != recipe(fold_config):
        raise ExperimentError(f"{where} was made by arm {record.get('arm')!r} with another training config than "
                              f"the arm resolves to now (its config file changed since): its figures would be "
                              f"filed under the wrong recipe; move it aside to train the fold again")


def runs(config, every: bool = False) -> list[Run]:
    """The runs this invocation trains (chosen arms and folds), or with `every` all the experiment's."""
    schemes = parse_names(config.schemes, SCHEMES, "scheme")
    folds = parse_folds("" if every else config.folds, config.k)
    arms = arm_names(config) if every else chosen_arms(config)
    return [Run(a, p, s, f) for a in arms for p in arm_protocols(config, a) for s in schemes
            for f in protocol_folds(p, folds)]
