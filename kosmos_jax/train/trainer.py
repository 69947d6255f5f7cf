"""The training loop: a config and a workdir in, checkpoints, metrics and a trained model out.

    train(config, workdir)

Run again on the same workdir, it resumes from the newest complete checkpoint (parameters,
optimiser state, step, the data iterator's position) and, from there, logs the same per-step losses
as a run never interrupted; a finished run says so and returns. SIGTERM (a preemption) saves at the
next step boundary and returns. A step whose loss or gradients are not finite stops the run with
an error naming the step and the batch's examples; the checkpoints already written stay as they are.

What is trained is a Task (train/task.py) chosen by config.task: "kosmos_e" (default, kosmos_task
below) or "baseline" (GR-ConvNet / GG-CNN2, train/baseline_task.py, configs/baselines.py).
"""

from __future__ import annotations

import copy
import dataclasses
import json
import pathlib
import shutil
import signal
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from kosmos_jax.dataset import samples as sample_stage
from kosmos_jax.models import value_embeddings, weights
from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_decoding import configured_windows
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.train import batches as batches_lib
from kosmos_jax.train import distributed, run_start, scene_stream
from kosmos_jax.train.auxiliary import AuxiliaryLosses
from kosmos_jax.train.baseline_task import baseline_task
from kosmos_jax.train.mesh import batch_sharding
from kosmos_jax.train.metrics_log import AUXILIARY_LOSSES, MetricsLog
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.train.state import abstract_train_state, init_train_state
from kosmos_jax.train.step import BATCH_KEYS, make_eval_step, make_train_step, train_keys
from kosmos_jax.train.task import Task, check_batch_layout, watched_record
from kosmos_jax.workdir.checkpoints import Checkpoints
from kosmos_jax.workdir.files import RUN_FILE, TOKENIZER_FILE, RunMismatchError
from kosmos_jax.workdir.model import model_config

class NonFiniteError(FloatingPointError):
    """A training step gave a loss or gradients that are not finite."""


def initial_params(config, model_cfg: Kosmos2Config, tokenizer, mesh, description: dict):
    """Fresh parameters, a run's (config.init_from = its workdir or exported folder; recorded in
    `description`["init"]), or KOSMOS-2's from config.init_from (their vocabulary must hold the tokenizer's)."""
    value_code = config.model.get("value_token_code", 0.0)  # .get: configs stored before the option
    if not config.init_from:
        if config.get("require_init"):
            raise ValueError(f"the {config.variant} variant starts from loaded weights: give "
                             "--config.init_from=FOLDER (config.json + model.safetensors)")
        model = build(model_cfg, config.train.seed)
        if value_code:
            embedding = model.text_model.model.embed_tokens.embedding
            embedding.set_value(jnp.asarray(value_embeddings.with_value_code(
                np.asarray(embedding.get_value()), tokenizer.piece_texts(), value_code,
                config.model.get("angle_code_bins", 0.0))))
        return split_model(model)[1]
    if value_code:
        raise ValueError("model.value_token_code sets the start of embeddings trained from scratch; "
                         "with config.init_from the embeddings are the loaded ones: leave it at 0")
    if run_start.is_start(config.init_from):
        step, params = run_start.start_params(config, model_cfg, mesh)
        description["init"] = {"from": str(pathlib.Path(config.init_from).resolve()), "step": step,
                               **({"exported": True} if run_start.is_export(config.init_from) else {})}
        return params
    model = weights.load_pretrained(config.init_from, seed=config.train.seed, compute_dtype=model_cfg.compute_dtype,
                                    remat=model_cfg.remat, scan_layers=model_cfg.scan_layers)
    if model.config.text.vocab_size < model_cfg.text.vocab_size:
        raise ValueError(f"{config.init_from}: a vocabulary of {model.config.text.vocab_size} cannot hold the "
                         f"tokenizer's {model_cfg.text.vocab_size} ids; build the data with KOSMOS-2's tokenizer "
                         "(--config.data.build.tokenizer=FOLDER/sentencepiece.bpe.model)")
    return nnx.state(model, nnx.Param)


class Preemption:
    """Remembers a SIGTERM so the loop can stop at a step boundary."""

    def __init__(self):
        self.requested = False
        self.previous = signal.signal(signal.SIGTERM, self._handle)

    def _handle(self, signum, frame):
        self.requested = True

    def restore(self):
        signal.signal(signal.SIGTERM, self.previous)


def prepare_data(data_config) -> batches_lib.Dataset:
    """Process 0 builds (or finds) the dataset first; the others then find the same build."""
    if jax.process_count() == 1:
        return batches_lib.prepare(data_config)
    from jax.experimental import multihost_utils

    dataset = batches_lib.prepare(data_config) if jax.process_index() == 0 else None
    multihost_utils.sync_global_devices("kosmos_jax dataset built")
    return dataset or batches_lib.prepare(data_config)


def run_description(config, dataset: batches_lib.Dataset, model_cfg) -> dict:
    return {"config": json.loads(config.to_json_best_effort()), "data_identity": dataset.identity,
            "dataset_dir": str(dataset.dir), "model": model_cfg.to_hf_dict(),
            # they change the forward pass; not in to_hf_dict; a field at its default is left out, as older runs wrote it
            "connector": {"grid_code": model_cfg.connector_grid_code,
                          **({"instruction": True} if model_cfg.connector_instruction else {})},
            "runtime": {"compute_dtype": model_cfg.compute_dtype},
            "rng": {"seed": config.train.seed, "dropout": "fold_in(fold_in(key(seed), stream), step), each row's mask by its example_index"}}


# What a description without a field stands for: runs made before the connector options, and the
# baselines, which have no connector, hold KOSMOS-2's
STORED_BEFORE = {"connector": {"grid_code": 0.0}, "data_stream": None}


def check_same_run(stored: dict, current: dict, workdir) -> None:
    for field, what in (("data_identity", "dataset"), ("data_stream", "scene stream"), ("model", "model"),
                        ("connector", "connector")):
        if stored.get(field, STORED_BEFORE.get(field)) != current.get(field, STORED_BEFORE.get(field)):
            raise RunMismatchError(f"{workdir} holds a run of another {what} than this config's; "
                                   "resume it with its own config or use a new --workdir")
    stored_seed, seed = stored.get("rng", {}).get("seed"), current.get("rng", {}).get("seed")
    if stored_seed != seed and stored_seed is not None:
        raise RunMismatchError(f"{workdir} holds a run of train.seed={stored_seed}, not {seed}; "
                               "resume it with its own seed or use a new --workdir")


DECAY_END = "decay_end"  # schedule_fields' key of the step the rate's decay ends at


def schedule_fields(description: dict) -> dict:
    """What a run description's learning-rate schedule is made of: the optimiser's settings, with the step
    its decay ends at (optimizer.decay_steps, or train.steps when that is 0) in place of decay_steps."""
    config = run_start.flat(description.get("config", {}))
    fields = {key: value for key, value in config.items() if key.startswith("optimizer.") and key != "optimizer.decay_steps"}
    if "train.steps" in config:
        fields[DECAY_END] = config.get("optimizer.decay_steps") or config["train.steps"]
    return fields


def schedule_change(stored: dict, current: dict) -> str | None:
    """"the rate decaying until step 400 (this config: 800)" or "optimizer.peak_lr=... (this config: ...)"
    when a run description's schedule differs from `current`'s; None when they agree. A run resumed under
    another one goes on under it from its checkpoint's step (how a run is lengthened)."""
    before, now = schedule_fields(stored), schedule_fields(current)
    differing = [key for key in sorted(before.keys() & now.keys()) if before[key] != now[key]]
    if not differing:
        return None
    key = differing[0]
    if key == DECAY_END:
        return f"the rate decaying until step {before[key]} (this config: {now[key]})"
    return f"{key}={before[key]!r} (this config: {now[key]!r})"


# Config fields that are paths on one machine, not what a run is
PATHS = ("data.root", "data.dir", "data.build.tokenizer")


def check_finished_run(stored_config: dict, config, workdir) -> None:
    """A finished run is found, not rebuilt, so its dataset and model cannot be compared as a resume
    compares them: its stored config's data, model and seed must be this config's, once a start has set
    the tokenizer as the run's own task did (fields that one of them lacks, added since, are not compared;
    nor the data's settings when config.data.dir names a build)."""
    if run_start.is_start(config.get("init_from", "")):  # a baseline's config has no start
        config = copy.deepcopy(config)
        run_start.use_run_tokenizer(config)
    stored, current = run_start.flat(stored_config), run_start.flat(json.loads(config.to_json_best_effort()))
    parts = ("model",) if config.data.get("dir") else ("data", "model")
    compared = [key for key in sorted(stored.keys() & current.keys())
                if (key.split(".")[0] in parts or key == "train.seed") and key not in PATHS]
    differing = [key for key in compared if stored[key] != current[key]]
    if differing:
        shown = ", ".join(f"{key}={stored[key]!r} (this config: {current[key]!r})" for key in differing[:3])
        raise RunMismatchError(f"{workdir} holds a finished run of another config: {shown}"
                               f"{' and more' if len(differing) > 3 else ''}; use a new --workdir")


def evaluate(eval_step, params, split, config, sharding) -> dict:
    totals = {"loss_sum": 0.0, "correct": 0, "tokens": 0}
    examples = 0
    for batch in batches_lib.eval_batches(split, config.train.batch_size, jax.process_index(), jax.process_count(),
                                       config.train.eval_batches):
        sums = jax.device_get(eval_step(params, distributed.process_batch({k: batch[k] for k in BATCH_KEYS}, sharding)))
        for key in totals:
            totals[key] += sums[key].item()
        examples += int((batch["example_index"] >= 0).sum())
    tokens = max(totals["tokens"], 1)
    return {"loss": totals["loss_sum"] / tokens, "accuracy": totals["correct"] / tokens, "tokens": totals["tokens"],
            "examples_per_process": examples}


def stream_settings(data_config) -> dict | None:
    """{"photos", "seed"[, "kinds"][, "examples"][, "targets"]} of config.data.stream when training reads scenes made on
    the fly, else None. "kinds" (resolved, e.g. ["non", "multi-name", ...]) is there only when
    config.data.stream.kinds gives the stream other instruction kinds than the build's, "examples" only when
    config.data.stream.examples caps a chunk's examples. The stream's seeds must all lie above the
    built dataset's scenes' seed, so that no test photo is ever a training one; config.data.kind_repeats,
    which weighs the built dataset's examples, is refused beside it."""
    stream = data_config.get("stream")
    if not stream or not stream.get("photos"):
        return None
    if data_config.get("kind_repeats"):
        raise ValueError("config.data.kind_repeats weighs the built dataset's examples, and the scene stream "
                         "(config.data.stream.photos > 0) makes its own: give one of them")
    if data_config.source == "synthetic" and stream.seed <= data_config.synthetic_seed:
        raise ValueError(f"config.data.stream.seed={stream.seed} must exceed config.data.synthetic_seed="
                         f"{data_config.synthetic_seed}: the stream's chunks take seeds seed, seed + 1, ..., and the "
                         "test split's scenes must not be among them")
    settings = {"photos": int(stream.photos), "seed": int(stream.seed)}
    if stream.get("kinds"):  # left out at the default, as runs made before the option wrote it
        single, multi = sample_stage.parse_kinds(batches_lib.kind_names(stream.kinds))
        settings["kinds"] = list(single) + [sample_stage.MULTI_PREFIX + k for k in multi]
    if stream.get("examples"):  # left out at the default, as for kinds
        settings["examples"] = int(stream.examples)
    if stream.get("targets"):  # likewise
        settings["targets"] = str(stream.targets)
    return settings


def check_label_source(auxiliary: AuxiliaryLosses, stream: dict | None) -> None:
    """The tower-label losses read each example's object labels, which only the scene stream attaches."""
    kinds = auxiliary.tower_labels()
    if kinds and not stream:
        raise ValueError(f"config.train.tower_{kinds[0]}_loss reads each example's object {kinds[0]}, which only the "
                         "scene stream attaches (from the scenes' metadata): give config.data.stream.photos > 0, or leave it 0")


def scene_batches(config, stream: dict, tokenizer, process_index: int = 0,
                  process_count: int = 1) -> scene_stream.SceneStream:
    """This process's training batches from scenes made on the fly (`stream` as `stream_settings` gives it):
    the build's stages and format, with the stream's own instruction kinds where it names them."""
    build = batches_lib.build_config(config.data)
    if "kinds" in stream:
        build = dataclasses.replace(build, kinds=tuple(stream["kinds"]))
    return scene_stream.SceneStream(build, tokenizer, photos=stream["photos"], seed=stream["seed"],
                                    global_batch=config.train.batch_size, process_index=process_index,
                                    process_count=process_count, examples=stream.get("examples", 0),
                                    targets=stream.get("targets", ""))


def kosmos_task(config, mesh, tx, schedule) -> Task:
    """KOSMOS-E: the built dataset's token batches, the language-model step, decoded grasps."""
    if run_start.is_start(config.init_from):
        run_start.use_run_tokenizer(config)
    dataset = prepare_data(config.data)
    tokenizer = dataset.tokenizer()
    model_cfg = model_config(config.model, tokenizer.vocab_size)
    check_batch_layout(config, mesh)
    description = run_description(config, dataset, model_cfg)
    splits = dataset.splits()
    stream = stream_settings(config.data)
    if stream:
        description["data_stream"] = stream
        batches = scene_batches(config, stream, tokenizer, jax.process_index(), jax.process_count())
        describe = batches.describe
    else:
        batches = batches_lib.train_batches(splits["train"], config.train.batch_size, config.train.seed,
                                         jax.process_index(), jax.process_count(),
                                         repeats=batches_lib.kind_repeats(config.data.get("kind_repeats", "")))
        describe = lambda host: batches_lib.describe_examples(splits["train"], host["example_index"])
    auxiliary = AuxiliaryLosses.from_config(config.train)
    check_label_source(auxiliary, stream)
    step_keys = train_keys(auxiliary)
    train_step = make_train_step(model_cfg, tx, schedule, mesh, microbatches=config.train.microbatches,
                                 seed=config.train.seed, auxiliary=auxiliary,
                                 angle_ids=value_embeddings.angle_token_ids(tokenizer.piece_texts()))
    eval_step = make_eval_step(model_cfg, mesh)
    sharding = batch_sharding(mesh)
    # the periodic evaluation reads the validation split when the dataset has one; the last one, test too
    watched = "validation" if "validation" in splits else "test"
    grasps = {name: GraspEvaluation(model_cfg, mesh, splits[name], tokenizer, FormatConfig(**dataset.identity["format"]),
                                    dataset.identity["build"]["protocol"], **configured_windows(config))
              for name in dict.fromkeys((watched, "test"))}
    grasps["test"].decoder = grasps[watched].decoder  # one decoder: its compiled programs serve both splits

    def step_record(step, metrics, host, step_s, waited):
        batch_size = config.train.batch_size
        return {"step": step, "loss": metrics["loss"], "accuracy": metrics["accuracy"],
                "learning_rate": metrics["learning_rate"], "grad_norm": metrics["grad_norm"],
                "update_norm": metrics["update_norm"], "param_norm": metrics["param_norm"],
                "loss_tokens": metrics["tokens"], "step_s": step_s,
                "examples_per_s": batch_size / step_s,
                "tokens_per_s": batch_size * host["tokens"].shape[1] / step_s,
                "data_wait_fraction": min(1.0, waited / step_s),
                **{name: metrics[name] for name in AUXILIARY_LOSSES if name in metrics}}

    def split_record(name, step, state, with_grasps: bool, log: MetricsLog) -> dict:
        """Loss and token accuracy on split `name`; with the grasp accuracy of decoded answers if asked."""
        record = {"step": step, "split": name, **evaluate(eval_step, state.params, splits[name], config, sharding)}
        if with_grasps:
            record["grasp_accuracy"] = grasps[name].grasp_accuracy(state.params)
            log.message(f"grasp accuracy ({name}) step {step}: {record['grasp_accuracy']:.2f}%")
        return record

    def test_record(step, state, with_grasps: bool, log: MetricsLog) -> dict:
        return watched_record(lambda name: split_record(name, step, state, with_grasps, log), watched != "test",
                              step, config.train.steps, log)

    return Task(
        description=description, batches=batches,
        init_state=lambda: init_train_state(initial_params(config, model_cfg, tokenizer, mesh, description), tx, mesh),
        abstract_state=lambda: abstract_train_state(model_cfg, tx, mesh),
        train_step=lambda state, host: train_step(state, distributed.process_batch(
            {k: host[k] for k in step_keys}, sharding)),
        step_record=step_record,
        describe=describe,
        test_record=test_record,
        write_files=lambda workdir: shutil.copyfile(dataset.tokenizer_path, workdir / TOKENIZER_FILE))


def make_task(config, mesh, tx, schedule) -> Task:
    kind = config.get("task", "kosmos_e")
    if kind == "kosmos_e":
        return kosmos_task(config, mesh, tx, schedule)
    if kind == "baseline":
        return baseline_task(config, mesh, tx, schedule)
    raise ValueError(f"config.task={kind!r}: expected 'kosmos_e' or 'baseline'")


def train(config, workdir) -> dict:
    """Train (or resume, or find finished) the run of `config` in `workdir`; returns a summary."""
    distributed.initialize_from_env()
    workdir = pathlib.Path(workdir)
    primary = jax.process_index() == 0
    steps = config.train.steps
    tx, schedule = make_optimizer(config.optimizer, steps)  # refuses a bad optimiser config before the workdir is made
    checkpoints = Checkpoints(workdir, keep=config.train.keep_checkpoints)
    latest = checkpoints.latest_step()
    if latest is not None and latest >= steps:
        stored = checkpoints.run_info(latest)
        checkpoints.close()
        check_finished_run(stored.get("config", {}), config, workdir)
        if primary:
            print(f"the run in {workdir} is finished: its newest checkpoint is step {latest} "
                  f"(train.steps={steps}); nothing to do", flush=True)
        return {"finished": True, "step": latest, "resumed_from": latest}

    mesh = make_mesh(config.mesh.data, config.mesh.fsdp, config.mesh.tensor)
    task = make_task(config, mesh, tx, schedule)
    batches = task.batches
    if latest is None:
        state = task.init_state()
        start = 0
    else:
        stored = checkpoints.run_info(latest)
        check_same_run(stored, task.description, workdir)
        changed = schedule_change(stored, task.description)
        if changed and primary:
            print(f"note: {workdir} began with {changed}: its learning-rate schedule changes from step {latest} on",
                  file=sys.stderr, flush=True)
        if "init" in stored:  # the start it was made from, not what config.init_from holds today
            task.description["init"] = stored["init"]
        state, data_state, _ = checkpoints.restore(latest, task.abstract_state())
        batches.set_state(data_state)
        start = latest
    if primary:
        workdir.mkdir(parents=True, exist_ok=True)
        (workdir / RUN_FILE).write_text(json.dumps(task.description, indent=1) + "\n")
        task.write_files(workdir)

    log = MetricsLog(workdir, steps, start, enabled=primary)
    if start:
        log.message(f"resuming {workdir} from step {start}")

    preemption = Preemption()
    step, stopped = start, None
    last_end = time.perf_counter()
    try:
        while step < steps:
            before = time.perf_counter()
            host = next(batches)
            waited = time.perf_counter() - before
            state, metrics = task.train_step(state, host)
            metrics = jax.device_get(metrics)
            step += 1
            if not metrics["finite"]:
                examples = task.describe(host)
                raise NonFiniteError(f"step {step}: loss {metrics['loss'].item()} or its gradients are not finite; "
                                     f"the batch held (this process's rows) {', '.join(examples)}. The state was not "
                                     f"updated and no checkpoint after step {checkpoints.latest_step()} was written")
            end = time.perf_counter()
            step_s, last_end = end - last_end, end
            if step % config.train.log_every == 0 or step == steps:
                log.write(task.step_record(step, metrics, host, step_s, waited))
            grasps_due = bool(config.train.grasp_eval_every) and step % config.train.grasp_eval_every == 0
            if ((config.train.eval_every and step % config.train.eval_every == 0) or grasps_due) and step < steps:
                log.write(task.test_record(step, state, grasps_due, log))
            if step % config.train.checkpoint_every == 0 or step == steps or preemption.requested:
                checkpoints.save(step, state, batches.get_state(), {**task.description, "step": step})
            if preemption.requested and step < steps:
                stopped = "preempted"
                log.message(f"SIGTERM: saved step {step} in {workdir}; the same command resumes from it")
                break
        if stopped is None:
            log.write(task.test_record(step, state, config.train.get("grasp_eval_at_end", True), log))
    finally:
        preemption.restore()
        checkpoints.close()
        log.close()
        if hasattr(batches, "close"):  # the scene stream's thread
            batches.close()
    return {"finished": stopped is None, "step": step, "resumed_from": start, "stopped": stopped}
