"""The train step and the eval step: pure functions of (state, batch), jitted with explicit shardings.

    train_step = make_train_step(model_config, tx, schedule, mesh, microbatches=4, seed=0)
    state, metrics = train_step(state, batch)      # state: TrainState on the mesh, donated
    metrics = make_eval_step(model_config, mesh)(state.params, batch)

A batch is a dict of arrays with the global batch on the leading axis (sharded over data and fsdp):
image uint8 [B, S, S, 3], tokens int32 [B, L], loss_mask and image_mask bool [B, L], length int32
[B], grasp float32 [B, 5] (the target grasp in the stored image's pixels, read only by the pointing
loss), example_index int [B] (each example's position in its split: its dropout masks' key); other
keys are ignored. The loss is the mean over the loss tokens of the whole global batch:
each microbatch adds its gradient of the loss SUM, divided once by the global token count, so any
number of microbatches gives the same update as one. Each row's dropout masks are drawn from
(seed, step, its example_index) only (`layers.dropout_per_example`): the same wherever the row sits
in the global batch, in whichever microbatch, on however many devices and processes, and a resumed
run repeats the masks of the run it resumes. A step whose loss or gradients are
not all finite returns the state it was given, unchanged, with metrics["finite"] False.

Each step traces under its mesh (jax.sharding.use_abstract_mesh inside the jitted function, since
jax.set_mesh is refused inside jit), so the model's `constrain` calls apply without the caller
setting a mesh, and `.lower()` works for AOT compilation against any devices the mesh holds.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from flax import nnx
from jax.sharding import Mesh

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.patch_grid import grid_side
from kosmos_jax.models.decoder import position_ids
from kosmos_jax.models.kosmos2 import Kosmos2, abstract_model, split_model
from kosmos_jax.models.layers import dropout_per_example
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.models.sharding import constrain, param_shardings
from kosmos_jax.train.auxiliary import AuxiliaryLosses
from kosmos_jax.train.loss import (answer_pointing_sum, circular_kernel, means, patch_angle_sum, pointing_sum,
                                   slot_angle_sum, slot_offset_sum, smoothed_angle_sum, token_sums, tower_angle_sum,
                                   tower_offset_sum)
from kosmos_jax.train.phrase_patch import phrase_patch_sum
from kosmos_jax.train.tower_labels import tower_label_sum
from kosmos_jax.train.mesh import batch_sharding, replicated
from kosmos_jax.train.state import TrainState, abstract_train_state

BATCH_KEYS = ("image", "tokens", "loss_mask", "image_mask", "length", "grasp")
TRAIN_KEYS = BATCH_KEYS + ("example_index",)  # the train step's: the examples' ids key their dropout masks
_DROPOUT_STREAM = 0x64726F70  # keeps dropout keys apart from the init's draws of the same seed


def train_keys(auxiliary: AuxiliaryLosses) -> tuple[str, ...]:
    """The batch fields the train step with these losses reads."""
    return TRAIN_KEYS + auxiliary.tower_labels()  # each label under its kind's name


def dropout_key(seed: int, step: jax.Array) -> jax.Array:
    """The dropout key of one step: a function of (seed, step) only. The model's dropout layers fold
    each row's example_index into it (`layers.dropout_per_example`), so no microbatch or place in the
    batch enters a mask."""
    base = jax.random.fold_in(jax.random.key(seed), _DROPOUT_STREAM)
    return jax.random.fold_in(base, step)


def rng_state(rest: nnx.State, key: jax.Array) -> nnx.State:
    """The model's non-parameter state with every RNG stream reseeded from `key` (each stream, and
    each entry of a stacked stream, its own key; counts at zero). Only shapes of `rest` are read."""
    variables, treedef = jax.tree.flatten(rest, is_leaf=lambda x: isinstance(x, nnx.Variable))

    def reseeded(index, var):
        if isinstance(var, nnx.RngKey):
            keys = jax.random.split(jax.random.fold_in(key, index), max(1, math.prod(var.shape)))
            return var.replace(keys.reshape(var.shape))
        if isinstance(var, nnx.RngCount):
            return var.replace(jnp.zeros(var.shape, var.dtype))
        raise TypeError(f"model state {type(var).__name__} is neither a parameter nor an RNG stream; "
                        "the train step does not carry it")

    return jax.tree.unflatten(treedef, [reseeded(i, var) for i, var in enumerate(variables)])


def image_features(model: Kosmos2, batch: dict[str, jax.Array]) -> jax.Array:
    """The vision tower's features [B, 1 + patches, D] of a batch's stored images."""
    return model.vision_model(pixels(batch["image"], model.config.vision.image_size))


def attention_mask(batch: dict[str, jax.Array]) -> jax.Array:
    return jnp.arange(batch["tokens"].shape[1])[None, :] < batch["length"][:, None]


def instruction(model: Kosmos2, batch: dict[str, jax.Array]) -> jax.Array | None:
    """The batch's instructions as a connector that reads them takes them (None for KOSMOS-2's)."""
    return model.instruction_bag(batch["tokens"], attention_mask(batch), batch["image_mask"], batch["loss_mask"])


def slots(model: Kosmos2, batch: dict[str, jax.Array], features: jax.Array | None = None) -> jax.Array:
    """The connector's image slots [B, Q, D] for a batch (from the tower's `features` when given)."""
    if features is None:
        features = image_features(model, batch)
    return model.image_to_text_projection(features, instruction(model, batch))


def logits(model: Kosmos2, batch: dict[str, jax.Array], image_embeds: jax.Array | None = None) -> jax.Array:
    """The model's logits [B, L, V] for a batch of stored examples (images as the processor prepares
    them), from the connector's `image_embeds` when the caller has them already."""
    if image_embeds is None:
        image_embeds = slots(model, batch)
    return model.text_model.logits(hidden_states(model, batch, image_embeds))


def hidden_states(model: Kosmos2, batch: dict[str, jax.Array], image_embeds: jax.Array) -> jax.Array:
    """The decoder's final hidden states [B, L, D] (float32) for a batch, from the connector's slots."""
    mask = attention_mask(batch)
    positions = position_ids(mask, model.config.text.pad_token_id)
    hidden, _ = model.text_model.model(batch["tokens"], mask, positions, image_embeds, batch["image_mask"])
    return hidden


def split_microbatches(batch: dict[str, jax.Array], microbatches: int) -> dict[str, jax.Array]:
    """[B, ...] -> [microbatches, B / microbatches, ...], microbatch m holding rows m, m + M, ...:
    with B sharded in contiguous blocks, each device's rows of every microbatch are its own."""

    def split(x):
        if x.shape[0] % microbatches:
            raise ValueError(f"batch of {x.shape[0]} does not split into {microbatches} microbatches")
        x = x.reshape(x.shape[0] // microbatches, microbatches, *x.shape[1:]).swapaxes(0, 1)
        return constrain(x, (None, "batch") + (None,) * (x.ndim - 2))

    return jax.tree.map(split, batch)


def _all_finite(tree) -> jax.Array:
    return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree)]))


def make_train_step(model_config: Kosmos2Config, tx: optax.GradientTransformation, schedule: optax.Schedule,
                    mesh: Mesh, *, microbatches: int = 1, seed: int = 0,
                    auxiliary: AuxiliaryLosses = AuxiliaryLosses(), angle_ids=None) -> Callable:
    """`train_step(state, batch) -> (state, metrics)`, jitted on `mesh`, the state donated.

    metrics (replicated scalars): loss, accuracy (next-token, on the loss tokens), learning_rate
    (of this update), grad_norm (before clipping), update_norm, param_norm (after), tokens (loss
    tokens of the global batch), finite; and each loss `auxiliary` adds (`AuxiliaryLosses.weights`),
    by its name, as its mean over the batch's loss tokens:
    - pointing: the connector's pointing cross-entropy (`loss.pointing_sum`, of the first
      `pointing_queries` latent queries when that is > 0, against `pointing_target`'s weights);
    - patch_angle: `loss.patch_angle_sum` of the connector's projected image tokens against the angle
      tokens' embedding rows (held fixed for it);
    - tower_angle: `loss.tower_angle_sum`, the tower's feature at the grasp's patch read as (cos, sin)
      of twice the angle; slot_angle: `loss.slot_angle_sum`, the same read of every image slot;
    - tower_offset / slot_offset: `loss.tower_offset_sum` and `loss.slot_offset_sum`, the same two
      places read for where in its patch the grasp's centre lies;
    - answer_pointing: `loss.answer_pointing_sum`, the decoder's states at the loss positions asked
      which image slot holds the target grasp's patch (the slots taught to be the patches);
    - phrase_patch: `phrase_patch.phrase_patch_sum`, each instruction's words matched with the tower's
      feature at its grasp's patch among the (micro)batch's;
    - tower_category / tower_colour: `tower_labels.tower_label_sum`, the tower's feature at the grasp's
      patch read as its object's category or main colour (the batch's labels, from the scene stream).
    Each is added to the loss with its weight. With `angle_smoothing` > 0 (a width in angle bins) the
    gradient is that of circular smooth labels on the angle tokens (`loss.smoothed_angle_sum`;
    angle_ids: each bin's token id), while `loss` stays the plain cross-entropy, comparable with runs
    without it.
    """
    angle_smoothing, weights = auxiliary.angle_smoothing, auxiliary.weights()
    for name, needed in (("angle_smoothing", angle_smoothing), ("patch_angle_loss", "patch_angle" in weights)):
        if needed and (angle_ids is None or len(angle_ids) == 0):
            raise ValueError(f"{name} needs the angle tokens' ids (a vocabulary with value tokens: "
                             "numbers=values and the angle code)")
    kernel = jnp.asarray(circular_kernel(len(angle_ids), angle_smoothing)) if angle_smoothing else None
    angle_ids = jnp.asarray(angle_ids, jnp.int32) if angle_smoothing or "patch_angle" in weights else None
    graphdef, _, rest = split_model(abstract_model(model_config))
    state_sharding = jax.tree.map(lambda x: x.sharding, abstract_train_state(model_config, tx, mesh))

    def loss_sum(params, batch, key):
        model = nnx.view(nnx.merge(graphdef, params, rng_state(rest, key)), deterministic=False)
        features = image_features(model, batch)
        image_embeds = slots(model, batch, features)
        hidden = hidden_states(model, batch, image_embeds)
        scores = model.text_model.logits(hidden)
        sums = token_sums(scores, batch["tokens"], batch["loss_mask"])
        objective = sums["loss_sum"]
        if angle_smoothing:
            objective = smoothed_angle_sum(scores, batch["tokens"], batch["loss_mask"], angle_ids, kernel)
        side = batch["image"].shape[1]
        if "pointing" in weights:
            log_probs = model.image_to_text_projection.pointing_log_probs(features, instruction(model, batch))
            sums["pointing_sum"] = pointing_sum(log_probs, batch["grasp"], side, batch["loss_mask"],
                                                 auxiliary.pointing_queries, auxiliary.pointing_target)
        if "patch_angle" in weights:
            rows = jax.lax.stop_gradient(model.text_model.model.embed_tokens.embedding[...][angle_ids])
            patch_tokens = model.image_to_text_projection.dense(features)
            sums["patch_angle_sum"] = patch_angle_sum(patch_tokens, rows, batch["grasp"], side, batch["loss_mask"])
        if "tower_angle" in weights:
            sums["tower_angle_sum"] = tower_angle_sum(features, batch["grasp"], side, batch["loss_mask"])
        if "slot_angle" in weights:
            sums["slot_angle_sum"] = slot_angle_sum(image_embeds, batch["grasp"], batch["loss_mask"])
        if "tower_offset" in weights:
            sums["tower_offset_sum"] = tower_offset_sum(features, batch["grasp"], side, batch["loss_mask"])
        if "slot_offset" in weights:
            sums["slot_offset_sum"] = slot_offset_sum(image_embeds, batch["grasp"], side,
                                                      grid_side(features.shape[1] - 1), batch["loss_mask"])
        if "phrase_patch" in weights:
            sums["phrase_patch_sum"] = phrase_patch_sum(features, model.text_model.model.embed_tokens.embedding[...],
                                                        batch["tokens"], attention_mask(batch), batch["image_mask"],
                                                        batch["loss_mask"], batch["grasp"], side)
        for kind in auxiliary.tower_labels():
            sums[f"tower_{kind}_sum"] = tower_label_sum(kind, features, batch[kind], batch["grasp"], side, batch["loss_mask"])
        if "answer_pointing" in weights:
            sums["answer_pointing_sum"] = answer_pointing_sum(hidden, batch["image_mask"], image_embeds.shape[1],
                                                               batch["grasp"], side, batch["loss_mask"])
        for name, weight in weights.items():
            objective = objective + weight * sums[f"{name}_sum"]
        return objective, sums

    def accumulate(params, step, parts):
        def gradient(part):
            with dropout_per_example(part["example_index"], model_config.dropout_mask_bits):  # a row's masks: its example's key
                grads, sums = jax.grad(loss_sum, has_aux=True)(params, part, dropout_key(seed, step))
            return jax.lax.with_sharding_constraint(grads, state_sharding.params), sums

        if microbatches == 1:  # no loop: on XLA:CPU a one-trip scan cost `small`'s step 15% (results/performance/cpu_step.md)
            return gradient(jax.tree.map(lambda x: x[0], parts))

        def add(carry, part):
            return jax.tree.map(jnp.add, carry, gradient(part)), None

        zero_sums = {"loss_sum": jnp.zeros((), jnp.float32), "correct": jnp.zeros((), jnp.int32),
                     "tokens": jnp.zeros((), jnp.int32), **{f"{name}_sum": jnp.zeros((), jnp.float32) for name in weights}}
        zero = (jax.tree.map(jnp.zeros_like, params), zero_sums)
        (grads, sums), _ = jax.lax.scan(add, zero, parts)
        return grads, sums

    def update(state, grads):
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        return TrainState(params, opt_state, state.step + 1), optax.tree.norm(updates)

    def skip(state, grads):  # a non-finite step: the caller raises, the last good state untouched
        return state, jnp.zeros((), jnp.float32)

    def train_step(state: TrainState, batch):
        with jax.sharding.use_abstract_mesh(mesh.abstract_mesh):
            parts = split_microbatches({key: batch[key] for key in train_keys(auxiliary)}, microbatches)
            grad_sum, sums = accumulate(state.params, state.step, parts)
            count = jnp.maximum(sums["tokens"], 1).astype(jnp.float32)
            grads = jax.tree.map(lambda g: g / count, grad_sum)
            finite = jnp.isfinite(sums["loss_sum"]) & _all_finite(grads)
            new_state, update_norm = jax.lax.cond(finite, update, skip, state, grads)
            metrics = {
                **means(sums),
                "learning_rate": jnp.asarray(schedule(state.step), jnp.float32),
                "grad_norm": optax.tree.norm(grads),
                "update_norm": update_norm,
                "param_norm": optax.tree.norm(new_state.params),
                "tokens": sums["tokens"],
                "finite": finite,
            }
        return new_state, metrics

    return jax.jit(train_step, in_shardings=(state_sharding, batch_sharding(mesh)),
                   out_shardings=(state_sharding, replicated(mesh)), donate_argnums=0)


def make_eval_step(model_config: Kosmos2Config, mesh: Mesh) -> Callable:
    """`eval_step(params, batch) -> metrics`: loss and next-token accuracy without dropout, and the
    sums (loss_sum, correct, tokens) to pool batches by, as replicated scalars."""
    graphdef, params, rest = split_model(abstract_model(model_config))

    def eval_step(params, batch):
        with jax.sharding.use_abstract_mesh(mesh.abstract_mesh):
            model = nnx.view(nnx.merge(graphdef, params, rng_state(rest, jax.random.key(0))), deterministic=True)
            sums = token_sums(logits(model, batch), batch["tokens"], batch["loss_mask"])
        return {**sums, **means(sums)}

    return jax.jit(eval_step, in_shardings=(param_shardings(params, mesh), batch_sharding(mesh)),
                   out_shardings=replicated(mesh))
