"""train.phrase_patch: an instruction's words matched with the tower's feature at its grasp's patch
among the batch's, against a numpy oracle; who takes part; the train step logs it."""

import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.train import loss, phrase_patch, step
from kosmos_jax.train.auxiliary import AuxiliaryLosses
from step_batches import one_tiny_step

SIDE, GRID, STORED = 4, 4, 224  # a 4 x 4 patch grid of a 224 px view
VISION, TEXT, VOCAB, LENGTH = 24, 16, 30, 10


def _log_softmax(x, axis):
    x = x - x.max(axis=axis, keepdims=True)
    return x - np.log(np.exp(x).sum(axis=axis, keepdims=True))


def _batch(rng, count):
    """Sequences <s> [2 image slots] </image> words... answer: the words are positions 4..7, the answer 8..9."""
    tokens = rng.integers(1, VOCAB, (count, LENGTH)).astype(np.int32)
    image_mask = np.zeros((count, LENGTH), bool)
    image_mask[:, 1:3] = True
    loss_mask = np.zeros((count, LENGTH), bool)
    loss_mask[:, 8:] = True
    attention = np.ones((count, LENGTH), bool)
    grasp = np.zeros((count, 5), np.float32)
    grasp[:, :2] = rng.uniform(0, STORED, (count, 2))
    return tokens, attention, image_mask, loss_mask, grasp


def _oracle(features, table, tokens, loss_mask, grasp, counted):
    """The loss written out in numpy for rows `counted` (their words at positions 4..7)."""
    words = table[tokens[:, 4:8]].mean(axis=1)
    words = words - words[counted].mean(axis=0)
    cells = np.clip(np.floor(np.nan_to_num(grasp[:, :2]) / STORED * GRID), 0, GRID - 1).astype(int)
    patches = features[np.arange(len(features)), 1 + cells[:, 1] * GRID + cells[:, 0]]
    avoid = np.concatenate([loss.tower_angle_directions(VISION), loss.offset_directions(VISION)], axis=1)
    size = min(phrase_patch.PHRASE_DIMENSIONS, VISION - 4, TEXT)
    patch_read = np.linalg.qr(np.concatenate([avoid, np.random.default_rng(2).normal(size=(VISION, size))], 1))[0][:, 4:]
    word_read = np.linalg.qr(np.random.default_rng(3).normal(size=(TEXT, size)))[0]
    unit = lambda v: v / np.linalg.norm(v, axis=1, keepdims=True)
    a, b = unit(words[counted] @ word_read), unit(patches[counted] @ patch_read)
    logits = a @ b.T / phrase_patch.TEMPERATURE
    own = np.arange(len(logits))
    per_row = 0.5 * (-_log_softmax(logits, 1)[own, own] - _log_softmax(logits, 0)[own, own])
    return float(np.sum(per_row * loss_mask[counted, 1:].sum(axis=1)))


def _sum(features, table, tokens, attention, image_mask, loss_mask, grasp):
    return float(phrase_patch.phrase_patch_sum(jnp.asarray(features), jnp.asarray(table), jnp.asarray(tokens),
                                               jnp.asarray(attention), jnp.asarray(image_mask), jnp.asarray(loss_mask),
                                               jnp.asarray(grasp), STORED))


def test_the_loss_is_the_mean_of_both_directions_cross_entropies_weighted_by_loss_tokens():
    rng = np.random.default_rng(0)
    tokens, attention, image_mask, loss_mask, grasp = _batch(rng, 6)
    features = rng.normal(size=(6, 1 + GRID * GRID, VISION)).astype(np.float32)
    table = rng.normal(size=(VOCAB, TEXT)).astype(np.float32)
    expected = _oracle(features.astype(np.float64), table.astype(np.float64), tokens, loss_mask, grasp, np.arange(6))
    assert _sum(features, table, tokens, attention, image_mask, loss_mask, grasp) == pytest.approx(expected, rel=1e-4)


def test_rows_without_words_or_a_target_grasp_take_no_part():
    rng = np.random.default_rng(1)
    tokens, attention, image_mask, loss_mask, grasp = _batch(rng, 6)
    features = rng.normal(size=(6, 1 + GRID * GRID, VISION)).astype(np.float32)
    table = rng.normal(size=(VOCAB, TEXT)).astype(np.float32)
    loss_mask[4] = False
    loss_mask[4, 4:] = True  # row 4: the answer starts right after </image>: no words (a NON example)
    grasp[5, :2] = np.nan  # row 5: no target grasp
    expected = _oracle(features.astype(np.float64), table.astype(np.float64), tokens, loss_mask, grasp, np.arange(4))
    got = _sum(features, table, tokens, attention, image_mask, loss_mask, grasp)
    assert got == pytest.approx(expected, rel=1e-4)
    features[4:] = rng.normal(size=features[4:].shape)
    assert _sum(features, table, tokens, attention, image_mask, loss_mask, grasp) == pytest.approx(got, rel=1e-6)
    loss_mask[1:4] = False  # one row left: nothing to tell it from
    assert _sum(features, table, tokens, attention, image_mask, loss_mask, grasp) == 0.0


def test_patches_that_hold_their_words_score_lower_than_shuffled_ones():
    rng = np.random.default_rng(2)
    count = 8
    tokens, attention, image_mask, loss_mask, grasp = _batch(rng, count)
    table = rng.normal(size=(VOCAB, TEXT)).astype(np.float32)
    words = table[tokens[:, 4:8]].mean(axis=1)
    words -= words.mean(axis=0)
    size = phrase_patch.phrase_dimensions(VISION, TEXT)
    avoid = np.concatenate([loss.tower_angle_directions(VISION), loss.offset_directions(VISION)], axis=1)
    patch_read = phrase_patch.shared_directions(VISION, size, 2, avoid)
    word_read = phrase_patch.shared_directions(TEXT, size, 3)
    features = np.zeros((count, 1 + GRID * GRID, VISION), np.float32)
    features[:, :] = (words @ word_read @ patch_read.T)[:, None, :]  # every patch of a view holds its words
    matched = _sum(features, table, tokens, attention, image_mask, loss_mask, grasp)
    shuffled = _sum(features[np.roll(np.arange(count), 1)], table, tokens, attention, image_mask, loss_mask, grasp)
    assert matched < 0.5 * shuffled


def test_the_shared_directions_are_orthonormal_and_avoid_the_angle_and_offset_reads():
    avoid = np.concatenate([loss.tower_angle_directions(VISION), loss.offset_directions(VISION)], axis=1)
    read = phrase_patch.shared_directions(VISION, phrase_patch.phrase_dimensions(VISION, TEXT), 2, avoid)
    np.testing.assert_allclose(read.T @ read, np.eye(read.shape[1]), atol=1e-6)
    np.testing.assert_allclose(avoid.T @ read, 0.0, atol=1e-6)
    with pytest.raises(ValueError, match="wider than 5"):
        phrase_patch.phrase_dimensions(5, 16)


@pytest.mark.slow  # one step of the tiny model (about 15 s on 2 cores)
def test_the_train_step_logs_the_phrase_patch_loss_of_the_model_it_updates():
    count = 4
    model, batch, metrics = one_tiny_step(AuxiliaryLosses(phrase_patch_loss=1.0), count, STORED)
    expected = phrase_patch.phrase_patch_sum(step.image_features(model, batch), model.text_model.model.embed_tokens.embedding[...],
                                             batch["tokens"], step.attention_mask(batch), batch["image_mask"],
                                             batch["loss_mask"], batch["grasp"], STORED) / (2 * count)
    assert float(metrics["phrase_patch"]) == pytest.approx(float(expected), rel=1e-5)
    assert float(expected) > 0
