"""train.tower_category: the tower's feature at the target grasp's patch read as its object's category,
against a numpy oracle; who takes part; a run without the scene stream refused; the train step logs it."""

import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.train import loss, step, tower_category, trainer
from kosmos_jax.train.auxiliary import AuxiliaryLosses
from kosmos_jax.train.phrase_patch import TEMPERATURE
from step_batches import one_tiny_step

GRID, STORED, VISION = 4, 224, 24  # a 4 x 4 patch grid of a 224 px view
CLASSES = len(tower_category.CATEGORY_NAMES)


def _inputs(rng, count):
    features = rng.normal(size=(count, 1 + GRID * GRID, VISION)).astype(np.float32)
    category = rng.integers(0, CLASSES, count).astype(np.int32)
    grasp = np.zeros((count, 5), np.float32)
    grasp[:, :2] = rng.uniform(0, STORED, (count, 2))
    loss_mask = np.arange(10)[None, :] >= 10 - rng.integers(1, 5, count)[:, None]
    return features, category, grasp, loss_mask  # the last 1 to 4 tokens of each row are its loss tokens


def _oracle(features, category, grasp, loss_mask, counted):
    """The loss written out in numpy for rows `counted`: directions from their own QR of the same draws."""
    cells = np.floor(np.nan_to_num(grasp[:, :2]) / STORED * GRID).astype(int)
    patches = features[np.arange(len(features)), 1 + cells[:, 1] * GRID + cells[:, 0]].astype(np.float64)
    avoid = np.concatenate([loss.tower_angle_directions(VISION), loss.offset_directions(VISION)], axis=1)
    draws = np.random.default_rng(4).normal(size=(VISION, CLASSES))
    read = np.linalg.qr(np.concatenate([avoid, draws], axis=1))[0][:, 4:4 + CLASSES]
    logits = patches / np.linalg.norm(patches, axis=1, keepdims=True) @ read / TEMPERATURE
    logits -= logits.max(axis=1, keepdims=True)
    log_p = logits - np.log(np.exp(logits).sum(axis=1, keepdims=True))
    rows = np.asarray(counted)
    return float(np.sum(-log_p[rows, category[rows]] * loss_mask[rows, 1:].sum(axis=1)))


def _sum(features, category, grasp, loss_mask):
    return float(tower_category.tower_category_sum(jnp.asarray(features), jnp.asarray(category), jnp.asarray(grasp),
                                                   STORED, jnp.asarray(loss_mask)))


def test_the_loss_is_the_categories_cross_entropy_weighted_by_loss_tokens():
    features, category, grasp, loss_mask = _inputs(np.random.default_rng(0), 6)
    expected = _oracle(features, category, grasp, loss_mask, range(6))
    assert _sum(features, category, grasp, loss_mask) == pytest.approx(expected, rel=1e-5)


def test_rows_without_a_category_or_a_target_grasp_take_no_part():
    rng = np.random.default_rng(1)
    features, category, grasp, loss_mask = _inputs(rng, 6)
    category[4] = tower_category.NO_CATEGORY
    grasp[5, :2] = np.nan
    got = _sum(features, category, grasp, loss_mask)
    assert got == pytest.approx(_oracle(features, category, grasp, loss_mask, range(4)), rel=1e-5)
    features[4:] = rng.normal(size=features[4:].shape)
    assert _sum(features, category, grasp, loss_mask) == pytest.approx(got, rel=1e-6)
    category[:] = tower_category.NO_CATEGORY
    assert _sum(features, category, grasp, loss_mask) == 0.0


def test_a_patch_along_its_categorys_direction_scores_lower_than_along_another():
    rng = np.random.default_rng(2)
    features, category, grasp, loss_mask = _inputs(rng, 8)
    read = tower_category.category_directions(VISION)
    features[:] = read.T[category][:, None, :]  # every patch points along its own category's read
    right = _sum(features, category, grasp, loss_mask)
    wrong = _sum(features, (category + 1) % CLASSES, grasp, loss_mask)
    assert right < 0.01 * wrong


def test_the_directions_are_orthonormal_avoid_the_angle_and_offset_reads_and_need_a_wide_tower():
    read = tower_category.category_directions(VISION)
    avoid = np.concatenate([loss.tower_angle_directions(VISION), loss.offset_directions(VISION)], axis=1)
    np.testing.assert_allclose(read.T @ read, np.eye(CLASSES), atol=1e-6)
    np.testing.assert_allclose(avoid.T @ read, 0.0, atol=1e-6)
    with pytest.raises(ValueError, match=f"at least {CLASSES + 4} wide"):
        tower_category.category_directions(CLASSES + 3)
    assert tower_category.category_label("Mug") == tower_category.CATEGORY_NAMES.index("Mug")
    with pytest.raises(ValueError, match="unknown synthetic category 'Cup'"):
        tower_category.category_label("Cup")


def test_a_run_without_the_scene_stream_is_refused():
    on = AuxiliaryLosses(tower_category_loss=1.0)
    with pytest.raises(ValueError, match="only the scene stream attaches"):
        trainer.check_category_source(on, None)
    trainer.check_category_source(on, {"photos": 8, "seed": 10_000})
    trainer.check_category_source(AuxiliaryLosses(), None)
    assert step.train_keys(on) == step.TRAIN_KEYS + (step.CATEGORY_KEY,)
    assert step.train_keys(AuxiliaryLosses()) == step.TRAIN_KEYS


@pytest.mark.slow  # one step of the tiny model (about 15 s on 2 cores)
def test_the_train_step_logs_the_tower_category_loss_of_the_model_it_updates():
    count = 4
    model, batch, metrics = one_tiny_step(AuxiliaryLosses(tower_category_loss=1.0), count, STORED,
                                          {step.CATEGORY_KEY: np.arange(count, dtype=np.int32)})
    expected = tower_category.tower_category_sum(step.image_features(model, batch), batch[step.CATEGORY_KEY],
                                                 batch["grasp"], STORED, batch["loss_mask"]) / (2 * count)
    assert float(metrics["tower_category"]) == pytest.approx(float(expected), rel=1e-5)
    assert float(expected) > 0
