"""The offset losses: the tower's grasp patch and every slot asked where in its patch the grasp's centre lies."""

import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.train import loss

SIDE, WIDTH, VIEW = 4, 8, 112  # a 4 x 4 grid of 28 px patches


def test_the_offset_is_where_the_centre_lies_in_its_patch_from_minus_one_to_one():
    centres = jnp.asarray([[1.5 / SIDE, 2.5 / SIDE], [1.0 / SIDE, 0.99], [0.0, 1.0], [0.3, -0.2]])
    np.testing.assert_allclose(loss.cell_offset(centres, SIDE), [[0, 0], [-1, 0.92], [-1, 1], [-0.6, -1]], atol=1e-5)


def test_the_offset_read_is_an_orthonormal_pair_apart_from_the_angle_read():
    directions = loss.offset_directions(WIDTH)
    np.testing.assert_allclose(directions.T @ directions, np.eye(2), atol=1e-6)
    np.testing.assert_allclose(directions.T @ loss.tower_angle_directions(WIDTH), 0.0, atol=1e-6)
    with pytest.raises(ValueError, match="at least 4"):
        loss.offset_directions(3)


def test_the_tower_offset_loss_reads_the_grasp_patch():
    directions = loss.offset_directions(WIDTH)
    grasp = jnp.asarray([[1.75 * 28, 2.25 * 28, 20.0, 10.0, 0.3]], jnp.float32)  # cell (1, 2), offset (0.5, -0.5)
    features = np.zeros((1, 1 + SIDE * SIDE, WIDTH), np.float32)
    features[0, 1 + 2 * SIDE + 1] = directions @ (loss.OFFSET_RADIUS * np.array([0.5, -0.5]))
    mask = jnp.asarray([[False, True, True]])  # two loss tokens
    assert float(loss.tower_offset_sum(jnp.asarray(features), grasp, VIEW, mask)) == pytest.approx(0.0, abs=1e-6)
    # the same grasp a quarter patch left and down, at its patch's centre: the read is off by 0.5 x the radius an axis
    moved = grasp.at[0, :2].add(jnp.asarray([-7.0, 7.0]))
    expected = 2 * 2 * (0.5 * loss.OFFSET_RADIUS) ** 2
    assert float(loss.tower_offset_sum(jnp.asarray(features), moved, VIEW, mask)) == pytest.approx(expected, rel=1e-5)
    # another patch's token is a zero read; a grasp without a centre adds nothing
    elsewhere = float(loss.tower_offset_sum(jnp.asarray(np.roll(features, 1, axis=1)), grasp, VIEW, mask))
    assert elsewhere == pytest.approx(2 * 2 * (0.5 * loss.OFFSET_RADIUS) ** 2, rel=1e-5)
    assert float(loss.tower_offset_sum(jnp.asarray(features), grasp.at[0, 1].set(jnp.nan), VIEW, mask)) == 0.0


def test_the_slot_offset_loss_reads_every_slot_at_unit_norm():
    directions = loss.offset_directions(WIDTH)
    target = directions @ (loss.OFFSET_RADIUS * np.array([0.5, -0.5]))
    rest = np.linalg.qr(np.c_[directions, np.random.default_rng(2).normal(size=(WIDTH, 1))])[0][:, 2]
    unit = target + rest * np.sqrt(1 - target @ target)  # norm 1, reads the target exactly
    slots = jnp.asarray(np.stack([unit, 5.0 * unit, -unit])[None], jnp.float32)
    grasp = jnp.asarray([[1.75 * 28, 2.25 * 28, 20.0, 10.0, 0.3]], jnp.float32)
    mask = jnp.asarray([[False, True, True]])
    # the first two read the target whatever their scale, the third its opposite: 2 tokens x the mean of 3
    expected = 2 * float(np.sum((2 * loss.OFFSET_RADIUS * np.array([0.5, -0.5])) ** 2)) / 3
    assert float(loss.slot_offset_sum(slots, grasp, VIEW, SIDE, mask)) == pytest.approx(expected, rel=1e-5)
    assert float(loss.slot_offset_sum(slots[:, :2], grasp, VIEW, SIDE, mask)) == pytest.approx(0.0, abs=1e-6)
