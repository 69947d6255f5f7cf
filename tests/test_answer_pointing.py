"""Slots that are the patches (pointing_target "identity") and the decoder asked which slot holds the
named object's grasp (answer_pointing_loss): the grounding options of configs/pretrain.py:demo_stream_ground."""

import dataclasses

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
import pytest
from flax import nnx

from kosmos_jax.models import config as model_config
from kosmos_jax.models import kosmos2, mesh
from kosmos_jax.train import loss, optimizer, state, step
from kosmos_jax.train.auxiliary import AuxiliaryLosses
from step_batches import answer_batch, constant_adamw

TINY = model_config.TINY
GRID = TINY.vision.image_size // TINY.vision.patch_size  # 8 x 8 patches
PATCH_SLOTS = TINY.replace(latent_query_num=GRID * GRID, connector_dense_std=1.0, connector_grid_code=1.0,
                           text=dataclasses.replace(TINY.text, dropout=0.0, attention_dropout=0.0))
STORED = 224


def _log_softmax(x, axis=-1):
    x = x - x.max(axis=axis, keepdims=True)
    return x - np.log(np.exp(x).sum(axis=axis, keepdims=True))


def test_identity_pointing_is_minus_each_querys_log_probability_of_its_own_patch_weighted_by_loss_tokens():
    batch, heads, side = 2, 3, 2
    queries = side * side
    log_probs = jnp.log(jax.nn.softmax(jax.random.normal(jax.random.key(0), (batch, heads, queries, 1 + 2 * queries)), -1))
    loss_mask = jnp.asarray([[0, 1, 1, 0], [0, 0, 0, 1]], bool)
    grasp = jnp.asarray([[10.0, 20.0, 5, 5, 0], [np.nan, np.nan, 5, 5, 0]])  # identity reads no grasp
    values = np.asarray(log_probs)
    expected = sum(-tokens * np.mean([values[row, :, q, 1 + q].mean() for q in range(queries)])
                   for row, tokens in enumerate([2, 1]))
    got = float(loss.pointing_sum(log_probs, grasp, STORED, loss_mask, target="identity"))
    assert got == pytest.approx(expected, rel=1e-6)
    with pytest.raises(ValueError, match="one latent query a patch"):
        loss.pointing_sum(log_probs[:, :, :3, :-1], grasp, STORED, loss_mask, target="identity")


def test_answer_pointing_is_the_cross_entropy_of_state_slot_scores_against_the_grasp_patch_at_loss_positions():
    batch, length, width, slots, start = 3, 10, 6, 4, 2  # a 2 x 2 grid of slots at positions 2..5
    hidden = np.random.default_rng(0).normal(size=(batch, length, width)).astype(np.float32)
    image_mask = np.zeros((batch, length), bool)
    image_mask[:, start:start + slots] = True
    loss_mask = np.zeros((batch, length), bool)
    loss_mask[0, [7, 8]] = loss_mask[1, 9] = loss_mask[2, 8] = True
    # centres: bottom left (slot 2), top right (slot 1), none (NaN: adds nothing)
    grasp = np.asarray([[10.0, 200.0, 5, 5, 0], [150.0, 20.0, 5, 5, 0], [np.nan, np.nan, 5, 5, 0]], np.float32)
    expected = 0.0
    for row, target in ((0, 2), (1, 1)):
        for position in np.flatnonzero(loss_mask[row]):
            scores = hidden[row, position - 1] @ hidden[row, start:start + slots].T / np.sqrt(width)
            expected -= _log_softmax(scores)[target]
    got = float(loss.answer_pointing_sum(jnp.asarray(hidden), jnp.asarray(image_mask), slots, jnp.asarray(grasp),
                                         STORED, jnp.asarray(loss_mask)))
    assert got == pytest.approx(expected, rel=1e-5)


@pytest.mark.parametrize("settings", [dict(answer_pointing_loss=1.0),
                                      dict(answer_pointing_loss=1.0, pointing_loss=1.0),
                                      dict(answer_pointing_loss=1.0, pointing_target="identity")])
def test_answer_pointing_is_refused_unless_the_slots_are_taught_to_be_the_patches(settings):
    with pytest.raises(ValueError, match="pointing_target='identity'"):
        AuxiliaryLosses(**settings)
    assert AuxiliaryLosses(**{**settings, "pointing_loss": 1.0, "pointing_target": "identity"}).weights() == {
        "pointing": 1.0, "answer_pointing": 1.0}


@pytest.mark.slow  # 20 s on 2 cores (2026-11-27): one step of the tiny model with 64 slots
def test_the_train_step_logs_the_answer_pointing_and_identity_pointing_of_the_model_it_updates():
    """Step 0's logged losses are the loss functions of the initial model's own states, per loss token."""
    on = mesh.make_mesh(1, 1, 1, devices=jax.devices()[:1])
    tx, schedule = optimizer.make_optimizer(constant_adamw(1e-3), total_steps=1)
    count, slots = 4, PATCH_SLOTS.latent_query_num
    batch = answer_batch(np.random.default_rng(0), count, slots, words=1, stored=STORED,
                         vocab=TINY.text.vocab_size)
    batch["grasp"][3, :2] = np.nan  # no target grasp: adds to neither loss's pointer term
    model = nnx.view(kosmos2.build(PATCH_SLOTS), deterministic=True)
    jnp_batch = {key: jnp.asarray(value) for key, value in batch.items()}
    features = step.image_features(model, jnp_batch)
    hidden = step.hidden_states(model, jnp_batch, model.image_to_text_projection(features))
    tokens = 2 * count
    expected = {
        "answer_pointing": loss.answer_pointing_sum(hidden, jnp_batch["image_mask"], slots, jnp_batch["grasp"], STORED,
                                                    jnp_batch["loss_mask"]) / tokens,
        "pointing": loss.pointing_sum(model.image_to_text_projection.pointing_log_probs(features), jnp_batch["grasp"],
                                      STORED, jnp_batch["loss_mask"], target="identity") / tokens}
    auxiliary = AuxiliaryLosses(pointing_loss=1.0, pointing_target="identity", answer_pointing_loss=2.0)
    train_step = step.make_train_step(PATCH_SLOTS, tx, schedule, on, seed=0, auxiliary=auxiliary)
    _, params, _ = kosmos2.split_model(model)
    _, metrics = train_step(state.init_train_state(params, tx, on), batch)
    for name, value in expected.items():
        assert float(metrics[name]) == pytest.approx(float(value), rel=1e-5)
    assert float(expected["answer_pointing"]) == pytest.approx(0.75 * np.log(slots), rel=0.2)  # 3 of 4 rows count


def test_the_pointer_diagnostic_counts_cells_and_quadrants_per_group():
    from kosmos_jax.diagnostics.answer_pointer import hit_shares, quadrants

    side = 8
    assert quadrants(np.asarray([0, 3, 4, 32, 63, 27, 36]), side).tolist() == [0, 0, 1, 2, 3, 0, 3]
    pointed = np.asarray([0, 1, 63, 36, 5])
    targets = np.asarray([0, 2, 62, 0, 5])
    groups = ["multi name", "multi name", "single non", "single non", "multi position"]
    shares = hit_shares(pointed, targets, groups, side)
    assert shares["all"] == {"examples": 5, "cell": 0.4, "quadrant": 0.8}
    assert shares["multi name"] == {"examples": 2, "cell": 0.5, "quadrant": 1.0}
    assert shares["single non"] == {"examples": 2, "cell": 0.0, "quadrant": 0.5}


def test_the_pointer_diagnostic_refuses_a_run_whose_slots_are_not_the_patches():
    import types

    from kosmos_jax.diagnostics.answer_pointer import answer_pointer
    from kosmos_jax.workdir.files import RunError

    run = types.SimpleNamespace(config=ml_collections.ConfigDict(dict(train=dict(pointing_target="cell"))),
                                workdir="runs/demo")
    with pytest.raises(RunError, match="pointing_target='identity'"):
        answer_pointer(run, "validation")
