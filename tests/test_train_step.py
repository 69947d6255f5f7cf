"""The training step on the tiny model: optimiser, loss normalisation, accumulation, non-finite
steps, dropout keys and per-example masks, and the same losses on a (data 2, fsdp 2, tensor 2) mesh
as on one device."""

import dataclasses
import functools
import json
import os
import re
import subprocess
import sys

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
import pytest
from flax import nnx
from jax.sharding import PartitionSpec

from kosmos_jax.models import config as model_config
from kosmos_jax.models import kosmos2, mesh
from kosmos_jax.models import layers
from kosmos_jax.models.layers import LayerNorm, dense
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.train import loss, optimizer, state, step

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TINY = model_config.TINY
NO_DROPOUT = TINY.replace(text=dataclasses.replace(TINY.text, dropout=0.0, attention_dropout=0.0))
BATCH, LENGTH = 8, 24
PROMPT = 3 + TINY.latent_query_num  # <s> <image> slots </image>
# Adam's eps for the exact comparisons: the first step lr * g / (|g| + eps) is then nearly linear in
# the gradient, so they see the accumulated gradients' rounding; at eps 1e-6, g / |g| blows the
# rounding of a near-zero gradient up to a whole step
LINEAR_EPS = 1.0


def _opt_config(**changes):
    values = dict(name="adamw", peak_lr=1e-2, end_lr=0.0, warmup_steps=0, decay_steps=None, b1=0.9, b2=0.98,
                  eps=1e-6, weight_decay=0.01, clip_norm=1.0)
    return ml_collections.ConfigDict({**values, **changes})


def _batch(seed=0, loss_tokens=None):
    """Random text after the image prompt as text/layout.py lays it out; `loss_tokens` [B]: how many
    tokens at the end of each row's text are targets (default: all text tokens)."""
    rng = np.random.default_rng(seed)
    length = rng.integers(PROMPT + 8, LENGTH + 1, BATCH).astype(np.int32)
    position = np.arange(LENGTH)[None, :]
    real = position < length[:, None]
    tokens = np.where(real, rng.integers(4, TINY.text.vocab_size, (BATCH, LENGTH)), TINY.text.pad_token_id)
    first_target = PROMPT if loss_tokens is None else length - np.asarray(loss_tokens)
    image_mask = np.zeros((BATCH, LENGTH), bool)
    image_mask[:, 2:2 + TINY.latent_query_num] = True
    return {
        "image": rng.integers(0, 256, (BATCH, 224, 224, 3), np.uint8),
        "tokens": tokens.astype(np.int32),
        "loss_mask": real & (position >= np.asarray(first_target).reshape(-1, 1)),
        "image_mask": image_mask,
        "length": length,
        "grasp": np.zeros((BATCH, 5), np.float32),  # other features of the pipeline's batch ride along
        "example_index": np.arange(100 * seed, 100 * seed + BATCH),  # int64, as the pipeline's: dropout's key
    }


@functools.lru_cache(maxsize=None)
def _model(cfg):
    return kosmos2.build(cfg)


@functools.lru_cache(maxsize=None)
def _params(cfg):
    _, params, _ = kosmos2.split_model(_model(cfg))
    return jax.device_get(params)


@functools.lru_cache(maxsize=None)
def _train_step(cfg, microbatches, mesh_shape=(1, 1, 1), eps=1e-6):
    devices = jax.devices()[: int(np.prod(mesh_shape))]
    on = mesh.make_mesh(*mesh_shape, devices=devices)
    tx, schedule = optimizer.make_optimizer(_opt_config(eps=eps), total_steps=10)
    return on, tx, step.make_train_step(cfg, tx, schedule, on, microbatches=microbatches, seed=0)


def _fresh_state(cfg, microbatches, mesh_shape=(1, 1, 1), params=None, eps=1e-6):
    on, tx, train_step = _train_step(cfg, microbatches, mesh_shape, eps)
    return state.init_train_state(_params(cfg) if params is None else params, tx, on), train_step


def _host(tree):
    return jax.tree.map(np.asarray, jax.device_get(tree))


# -- optimiser ------------------------------------------------------------------------------------

def test_schedule_warms_up_then_decays_linearly_to_end_lr():
    tx, schedule = optimizer.make_optimizer(_opt_config(peak_lr=2e-4, warmup_steps=375, decay_steps=30000), 99)
    values = [float(schedule(s)) for s in (0, 375 // 2, 375, (375 + 30000) // 2, 30000, 40000)]
    np.testing.assert_allclose(values, [0.0, 2e-4 * 187 / 375, 2e-4, 2e-4 * (1 - 14812 / 29625), 0.0, 0.0],
                               rtol=1e-6, atol=1e-12)
    _, by_total = optimizer.make_optimizer(_opt_config(peak_lr=1.0, warmup_steps=2), total_steps=12)
    assert float(by_total(7)) == pytest.approx(0.5) and float(by_total(12)) == 0.0



@pytest.mark.parametrize("rates,message", [
    (dict(peak_lr=0.0), "optimizer.peak_lr=0.0: a learning rate must be a positive number"),
    (dict(peak_lr=-1e-3), "optimizer.peak_lr=-0.001: a learning rate must be a positive number"),
    (dict(peak_lr=float("nan")), "optimizer.peak_lr=nan: a learning rate must be a positive number"),
    (dict(peak_lr=1e-3, end_lr=-1e-4), "optimizer.end_lr=-0.0001: must lie between 0 and optimizer.peak_lr=0.001"),
    (dict(peak_lr=1e-3, end_lr=2e-3), "optimizer.end_lr=0.002: must lie between 0 and optimizer.peak_lr=0.001"),
])
def test_make_optimizer_refuses_rates_no_run_means(rates, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        optimizer.make_optimizer(_opt_config(**rates), total_steps=10)


def test_decay_mask_spares_norms_biases_and_embeddings():
    params = _params(TINY)
    flat = {
        ".".join(map(str, path)): decays
        for path, decays in nnx.to_flat_state(optimizer.decay_mask(params, "logical"))
    }
    decaying = {name for name, decays in flat.items() if decays}
    assert "text_model.model.layers.0.ffn.fc1.kernel" in decaying
    assert "vision_model.model.embeddings.patch_embedding.kernel" in decaying
    assert "image_to_text_projection.x_attn.q_proj.kernel" in decaying
    assert all(name.endswith(".kernel") for name in decaying)
    spared = ("text_model.model.embed_tokens.embedding", "vision_model.model.embeddings.position_embedding.embedding",
              "vision_model.model.embeddings.class_embedding", "image_to_text_projection.latent_query",
              "text_model.model.layers.0.self_attn.inner_attn_ln.scale", "text_model.model.layers.0.ffn.fc1.bias")
    assert not decaying.intersection(spared) and set(spared) <= set(flat)
    by_path, by_axes = (jax.tree.leaves(optimizer.decay_mask(params, rule)) for rule in ("path", "logical"))
    assert by_path == by_axes


class _LinearNorm(nnx.Module):
    def __init__(self, rngs):
        self.linear = dense(3, 4, ("embed", "mlp"), rngs, std=0.5)
        self.norm = LayerNorm(4, 1e-5, rngs)


def test_update_matches_numpy_adamw_with_clipping_and_masked_decay():
    params = nnx.state(_LinearNorm(nnx.Rngs(0)), nnx.Param)
    cfg = _opt_config(peak_lr=0.1, warmup_steps=2, decay_steps=4, eps=1e-3, weight_decay=0.5, clip_norm=0.7)
    tx, schedule = optimizer.make_optimizer(cfg, total_steps=4)
    opt_state = tx.init(params)
    rng = np.random.default_rng(1)
    p = {"kernel": np.asarray(params["linear"]["kernel"][...]), "bias": np.asarray(params["linear"]["bias"][...])}
    m = {k: np.zeros_like(v) for k, v in p.items()}
    v = {k: np.zeros_like(x) for k, x in p.items()}
    for t in range(1, 4):
        g = {k: rng.normal(size=x.shape).astype(np.float32) for k, x in p.items()}
        grads = jax.tree.map(jnp.zeros_like, params)
        grads["linear"]["kernel"][...] = g["kernel"]
        grads["linear"]["bias"][...] = g["bias"]
        updates, opt_state = tx.update(grads, opt_state, params)
        params = jax.tree.map(lambda a, b: a + b, params, updates)
        scale = min(1.0, 0.7 / np.sqrt(sum(np.sum(x**2) for x in g.values())))  # norm params' grads are 0
        lr = 0.1 * min((t - 1) / 2, 1.0) if t - 1 < 2 else 0.1 * (1 - (t - 1 - 2) / 2)
        for k in p:
            gk = g[k] * scale
            m[k] = 0.9 * m[k] + 0.1 * gk
            v[k] = 0.98 * v[k] + 0.02 * gk**2
            adam = (m[k] / (1 - 0.9**t)) / (np.sqrt(v[k] / (1 - 0.98**t)) + 1e-3)
            p[k] = p[k] - lr * (adam + (0.5 * p[k] if k == "kernel" else 0.0))
        np.testing.assert_allclose(params["linear"]["kernel"][...], p["kernel"], rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(params["linear"]["bias"][...], p["bias"], rtol=1e-5, atol=1e-7)
        assert float(schedule(t - 1)) == pytest.approx(lr)
    np.testing.assert_array_equal(params["norm"]["scale"][...], np.ones(4))  # zero grads, no decay


# -- loss -----------------------------------------------------------------------------------------

def test_loss_mask_marks_targets_predicted_from_the_previous_position():
    tokens = jnp.array([[0, 5, 6, 7]])
    loss_mask = jnp.array([[False, False, True, True]])  # targets 6 and 7
    logits = jnp.full((1, 4, 9), -10.0).at[0, 1, 6].set(10.0).at[0, 2, 3].set(10.0)  # right, then wrong
    sums = loss.token_sums(logits, tokens, loss_mask)
    assert int(sums["tokens"]) == 2 and int(sums["correct"]) == 1
    log_p = jax.nn.log_softmax(logits[0])
    assert float(sums["loss_sum"]) == pytest.approx(-float(log_p[1, 6] + log_p[2, 7]), rel=1e-6)


@pytest.mark.slow  # 28 s (make test's --durations, 2026-12-02, 2 cores)
def test_loss_is_the_mean_over_loss_tokens_of_the_global_batch():
    batch = _batch(seed=3, loss_tokens=[1, 2, 3, 4, 5, 6, 7, 8])
    model = nnx.view(_model(NO_DROPOUT), deterministic=True)
    attention_mask = np.arange(LENGTH)[None, :] < batch["length"][:, None]
    logits = np.asarray(kosmos2.forward(model, batch["tokens"], attention_mask, batch["image_mask"],
                                        pixels=pixels(batch["image"], TINY.vision.image_size)), np.float64)
    shifted = logits[:, :-1] - logits[:, :-1].max(-1, keepdims=True)
    log_p = shifted - np.log(np.exp(shifted).sum(-1, keepdims=True))
    nll = -np.take_along_axis(log_p, batch["tokens"][:, 1:, None], -1)[..., 0]
    counted = batch["loss_mask"][:, 1:]
    expected = nll[counted].sum() / counted.sum()
    assert abs(expected - np.mean([row[c].mean() for row, c in zip(nll, counted)])) > 1e-3  # a different mean
    hits = (logits[:, :-1].argmax(-1) == batch["tokens"][:, 1:])[counted].mean()

    params = _params(NO_DROPOUT)
    train_state, train_step = _fresh_state(NO_DROPOUT, microbatches=4, params=params, eps=LINEAR_EPS)
    _, metrics = train_step(train_state, batch)
    assert int(metrics["tokens"]) == 36
    assert float(metrics["loss"]) == pytest.approx(expected, rel=1e-5)
    assert float(metrics["accuracy"]) == pytest.approx(hits, abs=1e-6)
    evaluated = step.make_eval_step(NO_DROPOUT, mesh.make_mesh(1, 1, 1, devices=jax.devices()[:1]))(params, batch)
    assert float(evaluated["loss"]) == pytest.approx(expected, rel=1e-5)
    assert int(evaluated["tokens"]) == 36 and float(evaluated["loss_sum"]) == pytest.approx(expected * 36, rel=1e-5)


# -- the step -------------------------------------------------------------------------------------

@pytest.mark.slow  # 30 s (make test's --durations, 2026-11-28, 2 cores)
def test_steps_lower_the_loss_on_a_fixed_batch():
    train_state, train_step = _fresh_state(TINY, microbatches=2)
    batch = _batch()
    losses = []
    for _ in range(4):
        train_state, metrics = train_step(train_state, batch)
        assert bool(metrics["finite"])
        losses.append(float(metrics["loss"]))
    assert losses[-1] < losses[0] - 0.5 and all(b < a for a, b in zip(losses, losses[1:])), losses
    assert int(train_state.step) == 4
    assert set(metrics) == {"loss", "accuracy", "learning_rate", "grad_norm", "update_norm", "param_norm", "tokens",
                            "finite"}
    assert float(metrics["learning_rate"]) == pytest.approx(1e-2 * (1 - 3 / 10))


@pytest.mark.slow  # 34 s (make test's --durations, 2026-11-27, 2 cores)
def test_steps_learn_an_answer_only_the_image_holds_once_the_connector_passes_the_image():
    """One prompt, eight photos, a different one-token answer to each: only the image path can lower
    the loss below log 8, and only with each row's own photo. At std 1 on unit-norm features, 200 steps
    learn it from the image: the loss with each row's own photo far below log 8, with another row's above it.
    At KOSMOS-2's connector init (std 0.02) the outcome is chaotic in float rounding and is not asserted:
    log 8 = 2.08 with the images unused on the machines of 2026-11-27, 1.75 on 2026-11-28's, 0.003 (learned)
    on 2026-12-05's, where std 1 ended at 0.196 (below 0.1 before)."""
    cfg = NO_DROPOUT.replace(connector_dense_std=1.0)
    on = mesh.make_mesh(1, 1, 1, devices=jax.devices()[:1])
    tx, schedule = optimizer.make_optimizer(_opt_config(peak_lr=3e-3, end_lr=3e-3), total_steps=200)
    train_step = step.make_train_step(cfg, tx, schedule, on, microbatches=1, seed=0)
    train_state = state.init_train_state(_params(cfg), tx, on)
    batch = _batch(seed=2, loss_tokens=np.ones(BATCH, int))
    batch["length"][:] = LENGTH
    batch["tokens"][:, :-1] = batch["tokens"][0, :-1]  # the same text before the answer in every row
    batch["tokens"][:, -1] = 10 + np.arange(BATCH)
    batch["loss_mask"] = np.zeros_like(batch["loss_mask"])
    batch["loss_mask"][:, -1] = True
    for _ in range(200):
        train_state, _ = train_step(train_state, batch)
    eval_step = step.make_eval_step(cfg, on)
    own = float(eval_step(train_state.params, batch)["loss"])
    swapped = float(eval_step(train_state.params, {**batch, "image": np.roll(batch["image"], 1, axis=0)})["loss"])
    # a quarter of log 8 with its own photo, more than log 8 with another's: the answer comes from the image
    assert own < np.log(BATCH) / 4 and swapped > np.log(BATCH), (own, swapped)


@pytest.mark.slow  # 38 s (make test's --durations, 2026-11-27, 2 cores)
def test_scanned_rematerialised_bfloat16_model_trains_and_decays_the_same_weights():
    options = TINY.replace(scan_layers=True, remat=True, compute_dtype="bfloat16")
    stacked, plain = _params(options), _params(TINY)

    def decaying_size(params):
        mask = optimizer.decay_mask(params)
        return sum(np.size(x) for decays, x in zip(jax.tree.leaves(mask), jax.tree.leaves(params)) if decays)

    assert decaying_size(stacked) == decaying_size(plain)
    train_state, train_step = _fresh_state(options, microbatches=2)
    losses = []
    for _ in range(3):
        train_state, metrics = train_step(train_state, _batch())
        assert bool(metrics["finite"])
        losses.append(float(metrics["loss"]))
    assert losses[-1] < losses[0] - 0.5, losses


@pytest.mark.slow  # 17 s (make test's --durations, 2026-12-02, 2 cores)
def test_four_microbatches_of_two_update_as_one_batch_of_eight():
    batch = _batch(seed=1)
    after = {}
    for microbatches in (1, 4):
        train_state, train_step = _fresh_state(NO_DROPOUT, microbatches, eps=LINEAR_EPS)
        new_state, metrics = train_step(train_state, batch)
        after[microbatches] = (_host(new_state.params), float(metrics["loss"]), float(metrics["grad_norm"]))
    (one, loss_one, norm_one), (four, loss_four, norm_four) = after[1], after[4]
    assert loss_four == pytest.approx(loss_one, rel=1e-6) and norm_four == pytest.approx(norm_one, rel=1e-5)
    before = jax.tree.leaves(_params(NO_DROPOUT))
    # The steps themselves, read back as (new - start). Summing the gradients in another order moves
    # each by float32 rounding of the sum's terms, whose scale is the largest step's, not the element's
    # (a gradient that cancels to ~0 keeps that absolute noise); and each new parameter was rounded to
    # float32, so a step is known only to within one spacing of the parameter it was added to.
    largest_step = max(float(np.abs(a - s).max()) for s, a in zip(before, jax.tree.leaves(one)))
    summation_noise = 8 * np.finfo(np.float32).eps * largest_step
    for start, a, b in zip(before, jax.tree.leaves(one), jax.tree.leaves(four)):
        resolution = np.spacing(np.maximum(np.abs(a), np.abs(b)))
        step_one, step_four = a - start, b - start
        allowed = 1e-3 * np.abs(step_one) + resolution + summation_noise
        assert np.all(np.abs(step_four - step_one) <= allowed), np.max(np.abs(step_four - step_one) - allowed)


def test_non_finite_step_returns_the_state_unchanged():
    params = jax.tree.map(np.array, _params(NO_DROPOUT))  # writable copies
    params["text_model"]["model"]["layer_norm"]["scale"][...] = np.full(TINY.text.embed_dim, np.inf, np.float32)
    train_state, train_step = _fresh_state(NO_DROPOUT, 1, params=params, eps=LINEAR_EPS)
    before = _host(train_state)
    new_state, metrics = train_step(train_state, _batch())
    assert not bool(metrics["finite"]) and not np.isfinite(float(metrics["loss"]))
    after = _host(new_state)
    assert int(after.step) == 0
    for a, b in zip(jax.tree.leaves(before), jax.tree.leaves(after)):
        np.testing.assert_array_equal(b, a)


@pytest.mark.slow  # 30 s (make test's --durations, 2026-12-02, 2 cores)
def test_dropout_keys_depend_on_seed_and_step_only():
    keys = {(seed, s): jax.random.key_data(step.dropout_key(seed, s)).tolist() for seed in (0, 1) for s in (0, 1)}
    assert len({json.dumps(k) for k in keys.values()}) == 4
    assert keys[(0, 1)] == jax.random.key_data(step.dropout_key(0, jnp.int32(1))).tolist()

    batch = _batch()
    losses = []
    for at_step in (0, 0, 5):
        train_state, train_step = _fresh_state(TINY, microbatches=2)
        train_state = train_state._replace(step=jax.device_put(jnp.int32(at_step), train_state.step.sharding))
        losses.append(float(train_step(train_state, batch)[1]["loss"]))  # the loss before the update: masks only
    assert losses[0] == losses[1] and losses[2] != losses[0]


def _permuted(batch, order):
    return {key: value[order] for key, value in batch.items()}


def test_a_rows_dropout_mask_follows_its_example_id_not_its_place():
    dropout = layers.Dropout(0.5, rngs=nnx.Rngs(dropout=3))
    ones = jnp.ones((6, 5, 7), jnp.float32)
    ids = jnp.asarray([10, 11, 12, 13, 14, 15])
    order = np.array([3, 0, 5, 1, 4, 2])

    def masks(ids, rows=ones):
        copy = nnx.clone(dropout)  # the same stream key and count each time
        with layers.dropout_per_example(ids):
            return np.asarray(copy(rows))

    first = masks(ids)
    assert 0.3 < np.mean(first == 0) < 0.7 and set(np.unique(first)) == {0.0, 2.0}
    np.testing.assert_array_equal(masks(ids[order]), first[order])  # a row's mask goes where it goes
    np.testing.assert_array_equal(masks(ids[:2], ones[:2]), first[:2])  # nor does the batch's size matter
    other = masks(ids.at[0].set(99))
    assert np.any(other[0] != first[0]) and np.array_equal(other[1:], first[1:])
    # outside the block, and off, it is nnx's own dropout
    np.testing.assert_array_equal(nnx.clone(dropout)(ones), nnx.Dropout(0.5, rngs=nnx.Rngs(dropout=3))(ones))
    with layers.dropout_per_example(ids):
        assert nnx.clone(dropout)(ones, deterministic=True) is ones


@pytest.mark.parametrize("mask_bits", [16, 8])
def test_masks_from_fewer_bits_drop_the_rounded_rate_and_follow_their_example(mask_bits):
    dropout = layers.Dropout(0.1, rngs=nnx.Rngs(dropout=5))
    ones = jnp.ones((4, 64, 1024), jnp.float32)
    ids = jnp.asarray([7, 8, 9, 10])

    def masks(ids, rows=ones, bits=mask_bits):
        with layers.dropout_per_example(ids, bits):
            return np.asarray(nnx.clone(dropout)(rows))

    out = masks(ids)
    dropped = round(0.1 * 2**mask_bits) / 2**mask_bits  # 0.1 rounded to the bits' resolution
    kept = np.unique(out[out != 0])
    np.testing.assert_allclose(kept, [1 / (1 - dropped)], rtol=1e-6)  # one float32 value: 1/keep
    # 262,144 draws: the dropped share within 5 standard deviations of the rounded rate
    assert abs(np.mean(out == 0) - dropped) < 5 * np.sqrt(dropped * (1 - dropped) / out.size)
    # neighbours come from one random word: each pair must still be dropped together only at the rate squared
    both = np.mean((out[..., :-1] == 0) & (out[..., 1:] == 0))
    assert abs(both - dropped**2) < 5 * np.sqrt(dropped**2 / out.size)
    np.testing.assert_array_equal(masks(ids[::-1], ones), out[::-1])
    assert not np.array_equal(masks(ids, bits=32) == 0, out == 0)  # other bits, other masks
    with pytest.raises(ValueError, match="mask_bits must be one of"):
        masks(ids, bits=4)


def test_an_unknown_dropout_mask_width_is_refused_by_the_model_config():
    with pytest.raises(ValueError, match=r"dropout_mask_bits must be one of \(32, 16, 8\), got 12"):
        TINY.replace(dropout_mask_bits=12)


@pytest.mark.slow  # 38 s (make test's --durations, 2026-11-27, 2 cores)
def test_a_rows_dropout_follows_its_example_through_the_train_step():
    """The loss (of the parameters before the update: dropout noise only) of a batch and of the same
    examples in another order, in one microbatch or two; another example id moves it."""
    batch = _batch()
    order = np.array([5, 2, 7, 0, 3, 6, 1, 4])
    losses = {}
    for microbatches in (1, 2):
        for name, rows in (("batch", batch), ("permuted", _permuted(batch, order)),
                           ("other ids", {**batch, "example_index": batch["example_index"] + 1000})):
            train_state, train_step = _fresh_state(TINY, microbatches)
            losses[microbatches, name] = float(train_step(train_state, rows)[1]["loss"])
    quiet_state, quiet_step = _fresh_state(NO_DROPOUT, 1)
    quiet = float(quiet_step(quiet_state, batch)[1]["loss"])
    reference = losses[1, "batch"]
    assert abs(reference - quiet) > 1e-3  # dropout is on
    # float32 sums of the same per-row terms in another order (and split in two): a few ulps
    for key in ((1, "permuted"), (2, "batch"), (2, "permuted")):
        assert losses[key] == pytest.approx(reference, rel=1e-6), key
    for microbatches in (1, 2):
        assert abs(losses[microbatches, "other ids"] - reference) > 1e-3


# -- the mesh -------------------------------------------------------------------------------------

def test_make_mesh_fills_one_axis_with_the_devices_left():
    assert mesh.mesh_shape((2, -1, 1), 8) == (2, 4, 1)
    assert mesh.mesh_shape((1, 1, 1), 1) == (1, 1, 1)
    for bad in ((3, -1, 1), (-1, -1, 1), (2, 2, 1), (0, -1, 1)):
        with pytest.raises(ValueError):
            mesh.mesh_shape(bad, 8)


def mesh_losses(mesh_shape, steps=3):
    """Per-step losses of the tiny model (dropout on, 2 microbatches) on a mesh of the first devices,
    and the shardings of one kernel and of its Adam moment."""
    train_state, train_step = _fresh_state(TINY, 2, tuple(mesh_shape))
    kernel = train_state.params["text_model"]["model"]["layers"][0]["self_attn"]["q_proj"]["kernel"]
    moment = train_state.opt_state[1][0].mu["text_model"]["model"]["layers"][0]["self_attn"]["q_proj"]["kernel"]
    losses = []
    for _ in range(steps):
        train_state, metrics = train_step(train_state, _batch())
        losses.append(float(metrics["loss"]))
    return {"losses": losses, "specs": [str(kernel.sharding.spec), str(moment.sharding.spec)]}


@pytest.mark.slow  # 51 s (make test's --durations, 2026-11-28, 2 cores)
def test_mesh_of_eight_devices_gives_the_losses_of_one():
    one = mesh_losses((1, 1, 1))
    if jax.device_count() >= 8:
        eight = mesh_losses((2, 2, 2))
    else:  # XLA_FLAGS came without 8 fake devices: they must be set before jax starts
        env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=8"}
        code = "import json, tests.test_train_step as t; print(json.dumps(t.mesh_losses((2, 2, 2))))"
        done = subprocess.run([sys.executable, "-c", code], env=env, cwd=REPO, capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-3000:]
        eight = json.loads(done.stdout.strip().splitlines()[-1])
    np.testing.assert_allclose(eight["losses"], one["losses"], rtol=1e-4)
    assert eight["specs"] == [str(PartitionSpec("fsdp", "tensor"))] * 2
