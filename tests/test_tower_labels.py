"""train.tower_labels: the tower's feature at the target grasp's patch read as its object's category or
main colour, against a numpy oracle; who takes part; a run without the scene stream refused; the train
step logs both."""

import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.train import loss, step, tower_labels, trainer
from kosmos_jax.train.auxiliary import AuxiliaryLosses
from kosmos_jax.train.phrase_patch import TEMPERATURE
from step_batches import one_tiny_step

GRID, STORED, VISION = 4, 224, 40  # a 4 x 4 patch grid of a 224 px view; wide enough for both label sets
KINDS = ("category", "colour")


def _classes(kind):
    return len(tower_labels.LABEL_NAMES[kind])


def _inputs(rng, count, kind):
    features = rng.normal(size=(count, 1 + GRID * GRID, VISION)).astype(np.float32)
    labels = rng.integers(0, _classes(kind), count).astype(np.int32)
    grasp = np.zeros((count, 5), np.float32)
    grasp[:, :2] = rng.uniform(0, STORED, (count, 2))
    loss_mask = np.arange(10)[None, :] >= 10 - rng.integers(1, 5, count)[:, None]
    return features, labels, grasp, loss_mask  # the last 1 to 4 tokens of each row are its loss tokens


def _read(kind):
    """The label set's directions from their own QR of the same seeded draws (categories: seed 4, after the
    angle and offset reads; colours: seed 5, after those and the categories' directions)."""
    avoid = [loss.tower_angle_directions(VISION), loss.offset_directions(VISION)]
    if kind == "colour":
        avoid.append(_read("category"))
    avoid = np.concatenate(avoid, axis=1)
    draws = np.random.default_rng({"category": 4, "colour": 5}[kind]).normal(size=(VISION, _classes(kind)))
    return np.linalg.qr(np.concatenate([avoid, draws], axis=1))[0][:, avoid.shape[1]:avoid.shape[1] + _classes(kind)]


def _oracle(kind, features, labels, grasp, loss_mask, counted):
    """The loss written out in numpy for rows `counted`."""
    cells = np.floor(np.nan_to_num(grasp[:, :2]) / STORED * GRID).astype(int)
    patches = features[np.arange(len(features)), 1 + cells[:, 1] * GRID + cells[:, 0]].astype(np.float64)
    logits = patches / np.linalg.norm(patches, axis=1, keepdims=True) @ _read(kind) / TEMPERATURE
    logits -= logits.max(axis=1, keepdims=True)
    log_p = logits - np.log(np.exp(logits).sum(axis=1, keepdims=True))
    rows = np.asarray(counted)
    return float(np.sum(-log_p[rows, labels[rows]] * loss_mask[rows, 1:].sum(axis=1)))


def _sum(kind, features, labels, grasp, loss_mask):
    return float(tower_labels.tower_label_sum(kind, jnp.asarray(features), jnp.asarray(labels), jnp.asarray(grasp),
                                              STORED, jnp.asarray(loss_mask)))


@pytest.mark.parametrize("kind", KINDS)
def test_the_loss_is_the_labels_cross_entropy_weighted_by_loss_tokens(kind):
    features, labels, grasp, loss_mask = _inputs(np.random.default_rng(0), 6, kind)
    expected = _oracle(kind, features, labels, grasp, loss_mask, range(6))
    assert _sum(kind, features, labels, grasp, loss_mask) == pytest.approx(expected, rel=1e-5)


@pytest.mark.parametrize("kind", KINDS)
def test_rows_without_a_label_or_a_target_grasp_take_no_part(kind):
    rng = np.random.default_rng(1)
    features, labels, grasp, loss_mask = _inputs(rng, 6, kind)
    labels[4] = tower_labels.NO_LABEL
    grasp[5, :2] = np.nan
    got = _sum(kind, features, labels, grasp, loss_mask)
    assert got == pytest.approx(_oracle(kind, features, labels, grasp, loss_mask, range(4)), rel=1e-5)
    features[4:] = rng.normal(size=features[4:].shape)
    assert _sum(kind, features, labels, grasp, loss_mask) == pytest.approx(got, rel=1e-6)
    labels[:] = tower_labels.NO_LABEL
    assert _sum(kind, features, labels, grasp, loss_mask) == 0.0


@pytest.mark.parametrize("kind", KINDS)
def test_a_patch_along_its_labels_direction_scores_lower_than_along_another(kind):
    rng = np.random.default_rng(2)
    features, labels, grasp, loss_mask = _inputs(rng, 8, kind)
    read = tower_labels.label_directions(kind, VISION)
    features[:] = read.T[labels][:, None, :]  # every patch points along its own label's read
    right = _sum(kind, features, labels, grasp, loss_mask)
    wrong = _sum(kind, features, (labels + 1) % _classes(kind), grasp, loss_mask)
    assert right < 0.01 * wrong


def test_the_directions_are_orthonormal_keep_apart_and_need_a_wide_tower():
    category, colour = (tower_labels.label_directions(kind, VISION) for kind in KINDS)
    avoid = np.concatenate([loss.tower_angle_directions(VISION), loss.offset_directions(VISION)], axis=1)
    for read in (category, colour):
        np.testing.assert_allclose(read.T @ read, np.eye(read.shape[1]), atol=1e-6)
        np.testing.assert_allclose(avoid.T @ read, 0.0, atol=1e-6)
    np.testing.assert_allclose(category.T @ colour, 0.0, atol=1e-6)  # the colour loss does not read categories
    categories, colours = _classes("category"), _classes("colour")
    with pytest.raises(ValueError, match=f"at least {categories + 4} wide"):
        tower_labels.label_directions("category", categories + 3)
    with pytest.raises(ValueError, match=f"at least {categories + colours + 4} wide"):
        tower_labels.label_directions("colour", categories + colours + 3)


def test_labels_are_names_places_and_unknown_names_are_refused():
    assert tower_labels.label_of("category", "Mug") == tower_labels.CATEGORY_NAMES.index("Mug")
    assert tower_labels.LABEL_NAMES["colour"][tower_labels.label_of("colour", "light blue")] == "light blue"
    with pytest.raises(ValueError, match="unknown synthetic category 'Cup'"):
        tower_labels.label_of("category", "Cup")
    with pytest.raises(ValueError, match="unknown synthetic colour 'mauve'"):
        tower_labels.label_of("colour", "mauve")
    with pytest.raises(ValueError, match="unknown object label kind 'size'"):
        tower_labels.label_of("size", "large")


def test_a_run_without_the_scene_stream_is_refused():
    for kind in KINDS:
        on = AuxiliaryLosses(**{f"tower_{kind}_loss": 1.0})
        with pytest.raises(ValueError, match=f"tower_{kind}_loss reads each example's object {kind}, which only the scene"):
            trainer.check_label_source(on, None)
        trainer.check_label_source(on, {"photos": 8, "seed": 10_000})
        assert step.train_keys(on) == step.TRAIN_KEYS + (kind,)
    trainer.check_label_source(AuxiliaryLosses(), None)
    assert step.train_keys(AuxiliaryLosses()) == step.TRAIN_KEYS
    both = AuxiliaryLosses(tower_category_loss=1.0, tower_colour_loss=0.5)
    assert step.train_keys(both) == step.TRAIN_KEYS + ("category", "colour")


@pytest.mark.slow  # one step of the tiny model (about 15 s on 2 cores)
def test_the_train_step_logs_the_tower_label_losses_of_the_model_it_updates():
    count = 4
    labels = {"category": np.arange(count, dtype=np.int32), "colour": np.arange(count, dtype=np.int32)[::-1].copy()}
    model, batch, metrics = one_tiny_step(AuxiliaryLosses(tower_category_loss=1.0, tower_colour_loss=0.3), count,
                                          STORED, labels, vision_width=VISION)
    for kind in KINDS:
        expected = tower_labels.tower_label_sum(kind, step.image_features(model, batch), batch[kind],
                                                batch["grasp"], STORED, batch["loss_mask"]) / (2 * count)
        assert float(metrics[f"tower_{kind}"]) == pytest.approx(float(expected), rel=1e-5)
        assert float(expected) > 0
