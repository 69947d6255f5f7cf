"""The connector's grid code and the pointing loss (options for models trained from scratch)."""

import dataclasses

import jax
import jax.numpy as jnp
import ml_collections
import numpy as np
import pytest
from flax import nnx

from kosmos_jax.models import config as model_config
from kosmos_jax.models import kosmos2, mesh, weights
from kosmos_jax.models.patch_grid import cell_centre, cell_index, grasp_cell_tokens, grid_code, grid_side
from kosmos_jax.models.preprocess import pixels
from kosmos_jax.train import loss, optimizer, state, step, trainer
from kosmos_jax.train.auxiliary import AuxiliaryLosses

TINY = model_config.TINY
NO_DROPOUT = TINY.replace(text=dataclasses.replace(TINY.text, dropout=0.0, attention_dropout=0.0))
GRID = TINY.vision.image_size // TINY.vision.patch_size  # 8 x 8 patches
STORED = 224


def test_the_grid_code_gives_each_cell_its_own_code_and_the_class_token_none():
    code = np.asarray(grid_code(16, 8))
    assert code.shape == (17, 8) and not code[0].any()
    distances = np.linalg.norm(code[1:, None] - code[None, 1:], axis=-1)
    assert (distances + np.eye(16) > 0.1).all()  # no two cells alike
    # x then y: cells of one row share the y half, cells of one column the x half
    np.testing.assert_allclose(code[1, 4:], code[4, 4:])
    np.testing.assert_allclose(code[1, :4], code[5, :4])
    with pytest.raises(ValueError, match="square grid"):
        grid_code(12, 8)
    with pytest.raises(ValueError, match="divisible by 4"):
        grid_code(16, 6)


def test_a_patch_cell_index_and_its_centre_invert_each_other_on_the_grid():
    """The cells the pointing loss and the vision probe's cells readout train on, and what the probe answers."""
    side = 4
    every = cell_centre(jnp.arange(side * side), side)
    assert np.allclose(every[5], [1.5 / side, 1.5 / side]) and np.allclose(every[side], [0.5 / side, 1.5 / side])
    assert np.array_equal(cell_index(every, side), np.arange(side * side))
    # a patch's corner belongs to it; the view's far edge and beyond to the last row/column
    assert cell_index(jnp.asarray([[0.25, 0.5], [1.0, 1.0], [-0.1, 2.0]]), side).tolist() == [9, 15, 12]
    assert grid_side(64) == 8
    with pytest.raises(ValueError, match="square grid"):
        grid_side(63)


@pytest.mark.slow  # 14 s (make test's --durations, 2026-11-28, 2 cores)
def test_with_a_grid_code_the_slots_ignore_what_every_image_token_shares():
    model = kosmos2.build(NO_DROPOUT.replace(connector_grid_code=1.0))
    features = jax.random.normal(jax.random.key(0), (2, 1 + GRID * GRID, TINY.vision.hidden_size))
    shared = jax.random.normal(jax.random.key(1), (TINY.vision.hidden_size,))
    connector = model.image_to_text_projection
    np.testing.assert_allclose(connector(features + shared), connector(features), atol=1e-5)
    kosmos_2 = kosmos2.build(NO_DROPOUT).image_to_text_projection
    assert np.abs(kosmos_2(features + shared) - kosmos_2(features)).max() > 1e-3


def test_pointing_sum_is_minus_the_log_probability_of_the_grasp_patch_weighted_by_loss_tokens():
    batch, heads, queries, patches = 3, 2, 3, 4
    keys = 1 + patches + queries
    log_probs = jnp.log(jax.nn.softmax(jax.random.normal(jax.random.key(0), (batch, heads, queries, keys)), -1))
    # centres in a 224 px view of a 2 x 2 grid: bottom-left, top-right, none (NaN)
    grasp = jnp.asarray([[10.0, 200.0, 5, 5, 0], [150.0, 20.0, 5, 5, 0], [np.nan, np.nan, 5, 5, 0]])
    loss_mask = jnp.asarray([[0, 1, 1, 0], [0, 1, 0, 0], [0, 1, 1, 1]], bool)
    expected = 0.0
    for row, (patch, tokens) in enumerate([(2, 2), (1, 1)]):  # row-major patch index, its loss tokens
        expected -= tokens * float(log_probs[row, :, :, 1 + patch].mean())
    assert float(loss.pointing_sum(log_probs, grasp, STORED, loss_mask)) == pytest.approx(expected, rel=1e-6)
    first_two = 0.0  # pointing only the first two latent queries: the third may look anywhere
    for row, (patch, tokens) in enumerate([(2, 2), (1, 1)]):
        first_two -= tokens * float(log_probs[row, :, :2, 1 + patch].mean())
    assert float(loss.pointing_sum(log_probs, grasp, STORED, loss_mask, queries=2)) == pytest.approx(first_two, rel=1e-6)
    assert first_two != pytest.approx(expected, rel=1e-3)


def test_bilinear_pointing_weights_average_the_patch_centres_to_the_grasp_centre():
    side = 4
    centres = jnp.asarray(np.random.default_rng(0).uniform(0.5 / side, 1 - 0.5 / side, (50, 2)))
    weights = np.asarray(loss.pointing_weights(centres, side, "bilinear"))
    assert weights.shape == (50, side * side) and (weights >= 0).all()
    np.testing.assert_allclose(weights.sum(-1), 1.0, rtol=1e-6)
    assert ((weights > 0).sum(-1) <= 4).all()
    # inside the band of patch centres the weighted mean of the patch centres is the grasp centre itself
    # (float32 positions of order 1: a few ulps)
    np.testing.assert_allclose(weights @ np.asarray(cell_centre(jnp.arange(side * side), side)), centres, rtol=1e-5)
    # at a patch's own centre all of it on that patch, as "cell" asks; beyond the outer centres, the border patch
    on_centres = cell_centre(jnp.asarray([0, 5, 15]), side)
    np.testing.assert_allclose(loss.pointing_weights(on_centres, side, "bilinear"),
                               loss.pointing_weights(on_centres, side, "cell"), atol=1e-6)
    corner = np.asarray(loss.pointing_weights(jnp.asarray([[0.01, 0.99]]), side, "bilinear"))[0]
    assert corner[12] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="pointing target"):
        loss.pointing_weights(centres, side, "nearest")


def test_bilinear_pointing_sum_is_the_cross_entropy_against_those_weights():
    batch, heads, queries, side = 2, 2, 3, 2
    log_probs = jnp.log(jax.nn.softmax(jax.random.normal(jax.random.key(0), (batch, heads, queries, 1 + side * side + queries)), -1))
    grasp = jnp.asarray([[84.0, 112.0, 5, 5, 0], [np.nan, np.nan, 5, 5, 0]])  # x a quarter of a cell right of centre 56
    loss_mask = jnp.asarray([[0, 1, 1], [0, 1, 1]], bool)
    # x: 56 -> 168 are the cell centres, 84 lies a quarter of the way; y 112 halfway between rows
    weights = np.array([0.75, 0.25, 0.75, 0.25]) * 0.5
    expected = -2 * float(np.sum(weights * np.asarray(log_probs[0, :, :, 1:1 + side * side]).mean(axis=(0, 1))))
    assert float(loss.pointing_sum(log_probs, grasp, STORED, loss_mask, target="bilinear")) == pytest.approx(expected, rel=1e-5)
    with pytest.raises(ValueError, match="pointing_target"):
        AuxiliaryLosses(pointing_loss=1.0, pointing_target="nearest")


def _squares(count, seed):
    """Grey images with one white square in a random patch cell, and that square's centre as the grasp."""
    rng = np.random.default_rng(seed)
    cells = rng.integers(0, GRID, (count, 2))
    side = STORED // GRID
    images = np.full((count, STORED, STORED, 3), 90, np.uint8)
    for image, (x, y) in zip(images, cells):
        image[y * side:(y + 1) * side, x * side:(x + 1) * side] = 255
    grasp = np.zeros((count, 5), np.float32)
    grasp[:, :2] = (cells + 0.5) * side
    return images, grasp, cells[:, 1] * GRID + cells[:, 0]


@pytest.mark.slow  # 27 s (make test's --durations, 2026-11-27 14:25, 2 cores)
def test_the_pointing_loss_teaches_the_latent_queries_to_look_at_the_grasp_patch_of_new_images():
    cfg = NO_DROPOUT.replace(connector_dense_std=1.0, connector_grid_code=1.0)
    on = mesh.make_mesh(1, 1, 1, devices=jax.devices()[:1])
    opt = ml_collections.ConfigDict(dict(name="adamw", peak_lr=3e-3, end_lr=3e-3, warmup_steps=0, decay_steps=None,
                                         b1=0.9, b2=0.98, eps=1e-6, weight_decay=0.0, clip_norm=1.0))
    tx, schedule = optimizer.make_optimizer(opt, total_steps=150)
    train_step = step.make_train_step(cfg, tx, schedule, on, microbatches=1, seed=0,
                                      auxiliary=AuxiliaryLosses(pointing_loss=1.0))
    graphdef, params, rest = kosmos2.split_model(kosmos2.build(cfg))
    train_state = state.init_train_state(params, tx, on)
    length, count = 3 + cfg.latent_query_num + 2, 16
    tokens = np.full((count, length), 5, np.int32)
    image_mask = np.zeros((count, length), bool)
    image_mask[:, 2:2 + cfg.latent_query_num] = True
    loss_mask = np.zeros((count, length), bool)
    loss_mask[:, -1] = True
    for seed in range(150):
        images, grasp, _ = _squares(count, seed)
        batch = dict(image=images, tokens=tokens, loss_mask=loss_mask, image_mask=image_mask,
                     length=np.full(count, length, np.int32), grasp=grasp, example_index=np.arange(count))
        train_state, metrics = train_step(train_state, batch)
        if seed == 0:
            first = float(metrics["pointing"])
    assert first == pytest.approx(np.log(1 + GRID * GRID + cfg.latent_query_num), abs=0.3)
    model = nnx.merge(graphdef, train_state.params, rest)
    images, _, cells = _squares(32, seed=10_000)  # images no step saw
    features = model.vision_model(pixels(images, cfg.vision.image_size))
    looked_at = jnp.argmax(model.image_to_text_projection.pointing_log_probs(features).mean(axis=(1, 2)), -1) - 1
    assert float(metrics["pointing"]) < first - 1.0
    assert (np.asarray(looked_at) == cells).mean() >= 0.9, (np.asarray(looked_at), cells)



def test_a_model_with_a_grid_code_is_not_exported_as_kosmos_2(tmp_path):
    with pytest.raises(ValueError, match="grid code"):
        weights.save_pretrained(kosmos2.build(TINY.replace(connector_grid_code=1.0)), tmp_path)
    assert not any(tmp_path.iterdir())


def test_a_run_resumes_only_with_its_own_connector(tmp_path):
    def description(grid_code):
        return {"data_identity": {"build": 1}, "model": {"layers": 2}, "connector": {"grid_code": grid_code}}

    older = {key: value for key, value in description(0.0).items() if key != "connector"}  # runs made before the option
    trainer.check_same_run(older, description(0.0), tmp_path)
    trainer.check_same_run(description(1.0), description(1.0), tmp_path)
    with pytest.raises(trainer.RunMismatchError, match="another connector"):
        trainer.check_same_run(older, description(1.0), tmp_path)
    with pytest.raises(trainer.RunMismatchError, match="another connector"):
        trainer.check_same_run(description(1.0), description(3.0), tmp_path)


def test_a_run_without_a_connector_resumes_and_still_checks_its_model(tmp_path):
    baseline = {"data_identity": {"build": 1}, "model": {"layers": 2}}  # what a baseline's run.json holds
    trainer.check_same_run(baseline, dict(baseline), tmp_path)
    with pytest.raises(trainer.RunMismatchError, match="another model"):
        trainer.check_same_run(baseline, {**baseline, "model": {"layers": 3}}, tmp_path)


def test_the_grasp_cell_token_is_the_token_of_the_patch_under_the_centre_past_the_class_token():
    side, width = 4, 3
    tokens = jnp.arange(2 * (1 + side * side) * width, dtype=jnp.float32).reshape(2, 1 + side * side, width)
    centres = jnp.asarray([[0.0, 0.0], [0.6, 0.3]])  # cells (0, 0) and (x 2, y 1): indices 0 and 6
    picked = grasp_cell_tokens(tokens, centres)
    assert np.array_equal(picked, np.stack([tokens[0, 1], tokens[1, 7]]))


@pytest.mark.slow  # 68 s (make test's --durations, 2026-11-27, 2 cores)
def test_the_train_step_logs_the_tower_and_slot_angle_and_offset_losses_of_the_model_it_updates():
    """Step 0's logged auxiliary losses are the loss functions of the initial model's own features and
    slots (dropout off), per loss token; each is logged only when its weight is set."""
    cfg = NO_DROPOUT.replace(connector_dense_std=1.0, connector_grid_code=1.0)
    on = mesh.make_mesh(1, 1, 1, devices=jax.devices()[:1])
    opt = ml_collections.ConfigDict(dict(name="adamw", peak_lr=1e-3, end_lr=1e-3, warmup_steps=0, decay_steps=None,
                                         b1=0.9, b2=0.98, eps=1e-6, weight_decay=0.0, clip_norm=1.0))
    tx, schedule = optimizer.make_optimizer(opt, total_steps=2)
    images, grasp, _ = _squares(4, seed=3)
    grasp[:, 4] = [0.3, -1.0, 1.2, 0.0]
    length = 3 + cfg.latent_query_num + 2
    image_mask = np.zeros((4, length), bool)
    image_mask[:, 2:2 + cfg.latent_query_num] = True
    loss_mask = np.zeros((4, length), bool)
    loss_mask[:, -2:] = True
    batch = dict(image=images, tokens=np.full((4, length), 5, np.int32), loss_mask=loss_mask, image_mask=image_mask,
                 length=np.full(4, length, np.int32), grasp=grasp, example_index=np.arange(4))
    model = kosmos2.build(cfg)
    features = model.vision_model(pixels(images, cfg.vision.image_size))
    expected = {"tower_angle": loss.tower_angle_sum(features, jnp.asarray(grasp), STORED, jnp.asarray(loss_mask)) / 8,
                "slot_angle": loss.slot_angle_sum(model.image_to_text_projection(features), jnp.asarray(grasp),
                                                  jnp.asarray(loss_mask)) / 8,
                "tower_offset": loss.tower_offset_sum(features, jnp.asarray(grasp), STORED, jnp.asarray(loss_mask)) / 8,
                "slot_offset": loss.slot_offset_sum(model.image_to_text_projection(features), jnp.asarray(grasp), STORED,
                                                    GRID, jnp.asarray(loss_mask)) / 8}
    for weights_set in ({"tower_angle_loss": 2.0}, {"tower_angle_loss": 2.0, "slot_angle_loss": 3.0},
                        {"tower_offset_loss": 1.0, "slot_offset_loss": 2.0}):
        train_step = step.make_train_step(cfg, tx, schedule, on, microbatches=2, seed=0,
                                          auxiliary=AuxiliaryLosses(**weights_set))
        _, params, _ = kosmos2.split_model(model)
        _, metrics = train_step(state.init_train_state(params, tx, on), batch)
        logged = {name for name in expected if name in metrics}
        assert logged == {name.removesuffix("_loss") for name in weights_set}
        for name in logged:
            assert float(metrics[name]) == pytest.approx(float(expected[name]), rel=1e-5)
