"""The trainer's baseline task (config.task = "baseline"): GR-ConvNet or GG-CNN2 on a fold's views.

    python -m kosmos_jax.train --config=configs/baselines.py:grconvnet_rgbd --workdir=W

The loop, optimiser, checkpoints and metrics are the trainer's (trainer.train); this module gives
what differs from KOSMOS-E: the views of a fold (baselines.inputs.fold_views from the photos of
config.data.source) and their batches, a pure function of (seed, step), so the data state of a
checkpoint is its step; the train state carries the BatchNorm running statistics as
`TrainState.model_state` (checkpointed and restored, never re-initialised); the step adds each
microbatch's loss sums and gradients (divided once by the global image count), each microbatch's
BatchNorm update starting from the previous one's, so the state keeps the last; the test record
scores `predict` (one grasp a view) with the rectangle metric under the run's protocol (under
`public`, the public code's detection, which may find no grasp, and its metric: baselines package
docstring). With config.data.validation_fraction > 0 the periodic records (train.eval_every) score
training photos held out as validation, and test only at the last step.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import NamedSharding, PartitionSpec

from kosmos_jax.baselines import inputs
from kosmos_jax.baselines.family import BaselineConfig, make_family
from kosmos_jax.sources import cornell
from kosmos_jax.metrics import grasp_success
from kosmos_jax.scoring.fold_scores import metric_settings
from kosmos_jax.train import batches as batches_lib
from kosmos_jax.train.mesh import batch_sharding, replicated
from kosmos_jax.train.state import TrainState
from kosmos_jax.train.step import _all_finite, dropout_key, split_microbatches
from kosmos_jax.train.task import Task, check_batch_layout, watched_record


class StepBatches:
    """Endless training batches of a fold's views; the iterator state is the next step."""

    def __init__(self, views: inputs.ViewArrays, batch_size: int, seed: int):
        self.views, self.batch_size, self.seed = views, batch_size, seed
        self.set_state({"step": 0})

    def __next__(self) -> dict:
        self.step += 1
        return next(self.iterator)

    def get_state(self) -> dict:
        return {"step": self.step}

    def set_state(self, state: dict) -> None:
        self.step = int(state["step"])
        self.iterator = inputs.batches(self.views, self.batch_size, self.seed, self.step)


def family_config(model) -> BaselineConfig:
    return BaselineConfig(network=model.network, mode=model.mode, channels=model.channels, loss=model.loss or None)


def data_identity(data) -> dict:
    """What the fold's views are made from; validation_fraction only when set, so runs made before it resume."""
    identity = {"source": str(batches_lib.source_folder(data)), **{name: data[name] for name in (
        "scheme", "protocol", "fold", "folds", "copies", "seed", "recipe")}}
    if data.get("validation_fraction"):
        identity["validation_fraction"] = float(data.validation_fraction)
    return identity


def load_views(data, mode: str) -> inputs.FoldViews:
    """The fold's train and test views of the photos config.data.source names (synthetic ones written first)."""
    photos = cornell.load_photos(batches_lib.source_folder(data))
    return inputs.fold_views(photos, mode, fold=data.fold, scheme=data.scheme, protocol=data.protocol, k=data.folds,
                             copies=data.copies, recipe=data.recipe, seed=data.seed,
                             validation_fraction=data.get("validation_fraction", 0.0))


def _replicated_like(tree, mesh):
    return jax.tree.map(lambda _: NamedSharding(mesh, PartitionSpec()), tree)


def initial_state(family, tx, seed: int) -> TrainState:
    """Step 0: fresh parameters and BatchNorm statistics, the optimiser's initial state."""
    _, params, rest = family.init(seed)
    return TrainState(params, tx.init(params), jnp.zeros((), jnp.int32), rest)


def abstract_state(family, tx, mesh) -> TrainState:
    """The train state's shapes, replicated on `mesh`: a checkpoint's restore target."""
    shapes = jax.eval_shape(lambda: initial_state(family, tx, 0))
    return jax.tree.map(lambda x, s: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=s),
                        shapes, _replicated_like(shapes, mesh))


def make_baseline_step(family, tx, schedule, mesh, state_sharding, *, microbatches: int = 1, seed: int = 0):
    """`step(state, batch) -> (state, metrics)`: the trainer's step for a baseline (see the module docstring).

    metrics: loss (the mean per image), each map's mean, learning_rate, grad_norm, update_norm,
    param_norm, images, finite.
    """

    def accumulate(params, rest, step, parts):
        def add(carry, indexed):
            grad_sum, sums, rest = carry
            index, part = indexed
            grads, (part_sums, rest) = jax.grad(family.loss_sums, has_aux=True)(
                params, rest, part, jax.random.fold_in(dropout_key(seed, step), index), True)
            return (jax.tree.map(jnp.add, grad_sum, grads), jax.tree.map(jnp.add, sums, part_sums), rest), None

        first = jax.tree.map(lambda x: x[0], parts)
        shapes = jax.eval_shape(lambda: family.loss_sums(params, rest, first, jax.random.key(0), True)[1][0])
        zero = (jax.tree.map(jnp.zeros_like, params), jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes), rest)
        # unrolled: XLA:CPU ran the convolutions inside a scan's loop ~20x slower (measured)
        (grad_sum, sums, rest), _ = jax.lax.scan(add, zero, (jnp.arange(microbatches), parts), unroll=True)
        return grad_sum, sums, rest

    def update(state, grads, rest):
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        return TrainState(params, opt_state, state.step + 1, rest), optax.tree.norm(updates)

    def skip(state, grads, rest):
        return state, jnp.zeros((), jnp.float32)

    def train_step(state: TrainState, batch):
        with jax.sharding.use_abstract_mesh(mesh.abstract_mesh):
            batch = {key: batch[key] for key in inputs.BATCH_KEYS}
            if microbatches == 1:  # no scan: XLA:CPU ran this one-step scan's convolutions ~20x slower
                grad_sum, (sums, rest) = jax.grad(family.loss_sums, has_aux=True)(
                    state.params, state.model_state, batch, jax.random.fold_in(dropout_key(seed, state.step), 0), True)
            else:
                parts = split_microbatches(batch, microbatches)
                grad_sum, sums, rest = accumulate(state.params, state.model_state, state.step, parts)
            count = jnp.maximum(sums["count"], 1).astype(jnp.float32)
            grads = jax.tree.map(lambda g: g / count, grad_sum)
            finite = jnp.isfinite(sums["loss_sum"]) & _all_finite(grads)
            new_state, update_norm = jax.lax.cond(finite, update, skip, state, grads, rest)
            means = {("loss" if name == "loss_sum" else name): value / count
                     for name, value in sums.items() if name != "count"}
            metrics = {**means, "learning_rate": jnp.asarray(schedule(state.step), jnp.float32),
                       "grad_norm": optax.tree.norm(grads), "update_norm": update_norm,
                       "param_norm": optax.tree.norm(new_state.params), "images": sums["count"], "finite": finite}
        return new_state, metrics

    return jax.jit(train_step, in_shardings=(state_sharding, batch_sharding(mesh)),
                   out_shardings=(state_sharding, replicated(mesh)), donate_argnums=0)


def test_scores(family, state, views: inputs.ViewArrays, batch_size: int, protocol: str) -> dict:
    """Loss (mean per view, running statistics) and the fraction of views whose one predicted grasp
    succeeds: `accuracy`, and as a percentage `grasp_accuracy` (KOSMOS-E's test lines' name), under
    the protocol's detection (family.predictor) and metric (fold_scores.metric_settings);
    `grasps_not_found`: views where the detection found no grasp (only the public one can)."""
    loss_sums = jax.jit(lambda params, rest, batch: family.loss_sums(params, rest, batch, jax.random.key(0), False)[0])
    predict = jax.jit(family.predictor(protocol))
    loss, grasps = 0.0, []
    for batch in inputs.eval_batches(views, batch_size):
        loss += float(loss_sums(state.params, state.model_state, batch))
        grasps.append(np.asarray(predict(state.params, state.model_state, batch["image"]))[batch["rows"] >= 0])
    grasps = np.concatenate(grasps)
    wh_policy, backend = metric_settings(protocol)
    success = float(np.mean(np.asarray(grasp_success(grasps, views.grasps, views.mask, backend=backend,
                                                     wh_policy=wh_policy))))
    return {"loss": loss / len(views), "accuracy": success, "grasp_accuracy": 100.0 * success, "views": len(views),
            "grasps_not_found": int(np.sum(~np.isfinite(grasps).all(axis=1)))}


def baseline_task(config, mesh, tx, schedule):

    check_batch_layout(config, mesh)
    family = make_family(family_config(config.model))
    views = load_views(config.data, family.config.mode)
    batch_size = config.train.batch_size
    description = {"config": config.to_dict(), "data_identity": data_identity(config.data),
                   "model": dataclasses.asdict(family.config), "missing_depth": views.missing_depth,
                   "views": {"train": len(views.train), "test": len(views.test),
                             **({"validation": len(views.validation)} if views.validation else {})},
                   "rng": {"seed": config.train.seed, "batches": "inputs.batch_rows(seed, step)"}}

    def fresh_state():
        return initial_state(family, tx, config.train.seed)

    state_sharding = _replicated_like(jax.eval_shape(fresh_state), mesh)
    train_step = make_baseline_step(family, tx, schedule, mesh, state_sharding,
                                    microbatches=config.train.microbatches, seed=config.train.seed)

    def step_record(step, metrics, host, step_s, waited):
        return {"step": step, **{name: value for name, value in metrics.items() if name != "finite"},
                "step_s": step_s, "examples_per_s": batch_size / step_s,
                "data_wait_fraction": min(1.0, waited / step_s)}

    def split_record(name, step, state, log) -> dict:
        record = {"step": step, "split": name, **test_scores(family, state, getattr(views, name), batch_size,
                                                              config.data.protocol)}
        log.message(f"grasp accuracy ({name}) step {step}: {record['grasp_accuracy']:.2f}%")
        return record

    def test_record(step, state, with_grasps, log):
        return watched_record(lambda name: split_record(name, step, state, log), views.validation is not None,
                              step, config.train.steps, log)

    return Task(
        description=description, batches=StepBatches(views.train, batch_size, config.train.seed),
        init_state=lambda: jax.jit(fresh_state, out_shardings=state_sharding)(),
        abstract_state=lambda: abstract_state(family, tx, mesh),
        train_step=lambda state, host: train_step(state, {k: jnp.asarray(host[k]) for k in inputs.BATCH_KEYS}),
        step_record=step_record,
        describe=lambda host: [f"{views.train.photo_id[r]} (copy {views.train.copy[r]})" for r in host["rows"]],
        test_record=test_record,
        write_files=lambda workdir: None)
