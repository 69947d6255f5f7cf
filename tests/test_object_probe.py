"""diagnostics.object_probe and diagnostics.readouts: which quadrant a patch is in, class readouts,
what each photo's object is (seeing) and which quadrant the instruction names (routing)."""

import json

import numpy as np
import pytest

from kosmos_jax.diagnostics import object_probe as probe
from kosmos_jax.diagnostics import readouts
from kosmos_jax.workdir.files import RunError


def test_quadrants_of_a_four_by_four_grid_are_its_two_by_two_blocks_in_reading_order():
    assert probe.quadrant_of_patches(4).reshape(4, 4).tolist() == [[0, 0, 1, 1], [0, 0, 1, 1], [2, 2, 3, 3],
                                                                  [2, 2, 3, 3]]


def test_a_class_readout_finds_classes_the_features_hold_and_noise_scores_near_the_majority():
    rng = np.random.default_rng(0)
    labels = rng.integers(0, 5, 3000)
    noise = rng.normal(size=(3000, 8))
    holding = np.c_[np.eye(5)[labels] + 0.1 * noise[:, :5], noise]
    read = readouts.class_readout(holding[:2000], labels[:2000], 5, ridge=1e-3)
    assert readouts.accuracy(read(holding[2000:]), labels[2000:]) > 99
    blind = readouts.class_readout(noise[:2000], labels[:2000], 5, ridge=1e-3)
    assert readouts.accuracy(blind(noise[2000:]), labels[2000:]) < 26  # chance is 20%, 1,000 draws
    assert readouts.majority_share(np.array([1, 1, 2]), np.array([1, 2, 2, 2])) == 25.0


def _read(rng, count, see, route):
    """Stage features of `count` mosaics: tiles hold their photo's category when `see`, the decoder
    holds the target quadrant when `route`; half the mosaics are of the position kind."""
    categories = ["Box", "Can", "Mug"]
    photos = np.asarray([f"p{i}" for i in range(4 * count)]).reshape(count, 4)
    category_of = {p: categories[i % 3] for i, p in enumerate(photos.reshape(-1))}
    codes = np.asarray([[categories.index(category_of[p]) for p in row] for row in photos])
    tiles = rng.normal(size=(count, 4, 6))
    if see:
        tiles[..., :3] += 4 * np.eye(3)[codes]
    target = rng.integers(0, 4, count)
    decoder = rng.normal(size=(count, 5))
    if route:
        decoder[:, :4] += 4 * np.eye(4)[target]
    kinds = np.where(np.arange(count) % 2 == 0, "position", "name")
    labels = {p: (category_of[p], "red") for p in photos.reshape(-1)}
    at_target = tiles[np.arange(count), target]
    return {"tiles": tiles, "at_target": at_target, "slots": rng.normal(size=(count, 5)), "decoder": decoder,
            "target": target, "kind": kinds, "photos": photos}, labels


def test_seeing_and_routing_tell_a_tower_that_sees_from_a_decoder_that_routes():
    rng = np.random.default_rng(2)
    train, labels = _read(rng, 800, see=True, route=False)
    scored, scored_labels = _read(rng, 400, see=True, route=False)
    seen = probe.seeing(train, scored, {**labels, **scored_labels}, ridge=1e-3)
    assert seen["category"]["test"] > 95 and seen["category"]["classes"] == 3
    assert seen["colour"] == {"test": 100.0, "train": 100.0, "majority": 100.0, "classes": 1}
    assert probe.seeing(train, scored, {**labels, **scored_labels}, ridge=1e-3, place="at_target")["category"]["test"] > 95
    routed = probe.routing(train, scored, ridge=1e-3)
    assert set(routed) == {"position", "object"} and routed["object"]["test_examples"] == 200
    assert routed["object"]["decoder"]["test"] < 40  # chance is 25% on 200 mosaics
    train, labels = _read(rng, 800, see=False, route=True)
    scored, scored_labels = _read(rng, 400, see=False, route=True)
    assert probe.seeing(train, scored, {**labels, **scored_labels}, ridge=1e-3)["category"]["test"] < 45
    assert probe.routing(train, scored, ridge=1e-3)["object"]["decoder"]["test"] > 95


def test_a_source_without_synthetic_metadata_is_refused_by_name(tmp_path):
    with pytest.raises(RunError, match="synthetic_meta.json is missing"):
        probe.photo_labels(tmp_path)
    (tmp_path / "synthetic_meta.json").write_text(json.dumps(
        {"photos": {"pcd0100": {"category": "Mug", "colour": ["red", "white"]}}}))
    assert probe.photo_labels(tmp_path) == {"pcd0100": ("Mug", "red")}


def test_the_command_refuses_a_missing_workdir_with_one_line(tmp_path, capsys):
    assert probe.main([f"--workdir={tmp_path / 'absent'}"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:")


def test_quadrant_pixels_average_each_quadrant_in_reading_order():
    images = np.zeros((1, 32, 32, 3), np.uint8)
    images[0, :16, 16:] = 255  # top right white
    images[0, 16:, :16, 0] = 51  # bottom left a fifth red
    pooled = probe.quadrant_pixels(images, side=2)
    assert pooled.shape == (1, 4, 12)
    np.testing.assert_allclose(pooled[0].reshape(4, 4, 3).mean(axis=1), [[0, 0, 0], [1, 1, 1], [0.2, 0, 0], [0, 0, 0]])


def test_patch_pixels_are_the_pixels_of_the_patch_holding_the_centre():
    images = np.zeros((2, 28, 28, 3), np.uint8)
    images[:, 14:, :14] = 200  # the bottom left patch of a 2 x 2 grid
    pooled = probe.patch_pixels(images, np.array([[0.2, 0.9], [0.9, 0.2]]), side=2, pooled=7)
    assert pooled.shape == (2, 147)
    np.testing.assert_allclose(pooled[0], 200 / 255)
    np.testing.assert_allclose(pooled[1], 0.0)
