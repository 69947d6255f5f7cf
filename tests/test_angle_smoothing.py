"""Circular smooth labels on angle tokens (train.loss.smoothed_angle_sum): near angle bins, across the
wrap from a_255 to a_0 too, are near misses; every other token keeps the plain cross-entropy."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.train import loss
from kosmos_jax.train.auxiliary import AuxiliaryLosses

BINS = 256
VOCAB = 300
ANGLE_IDS = np.arange(40, 40 + BINS, dtype=np.int32)  # a_k is token 40 + k


def _batch(targets):
    """tokens [1, 1 + n]: <s> then the targets; every target counted."""
    tokens = jnp.asarray([[1, *targets]], jnp.int32)
    return tokens, jnp.ones_like(tokens, bool)


def _peaked_logits(peaks, vocab=VOCAB):
    """logits [1, 1 + n, V] whose position t puts most of its mass on peaks[t]."""
    logits = np.zeros((1, len(peaks) + 1, vocab), np.float32)
    for t, peak in enumerate(peaks):
        logits[0, t, peak] = 8.0
    return jnp.asarray(logits)


def test_kernel_rows_are_wrapped_normalised_gaussians():
    kernel = loss.circular_kernel(BINS, 8.0)
    np.testing.assert_allclose(kernel.sum(axis=1), 1.0, rtol=1e-6)
    assert kernel[0, 1] == kernel[0, BINS - 1] and kernel[0, 5] == kernel[10, 15]
    assert kernel[0, 0] > kernel[0, 8] > kernel[0, 24] > kernel[0, 128]
    assert kernel[0, 8] / kernel[0, 0] == pytest.approx(np.exp(-0.5), rel=1e-5)


def test_a_narrow_kernel_is_the_plain_cross_entropy():
    tokens, mask = _batch([7, 40 + 3, 40 + 200, 12])
    logits = jax.random.normal(jax.random.key(0), (1, 5, VOCAB))
    plain = loss.token_sums(logits, tokens, mask)["loss_sum"]
    narrow = loss.smoothed_angle_sum(logits, tokens, mask, jnp.asarray(ANGLE_IDS), jnp.asarray(loss.circular_kernel(BINS, 1e-3)))
    assert float(narrow) == pytest.approx(float(plain), rel=1e-6)


def test_other_tokens_keep_the_plain_cross_entropy():
    tokens, mask = _batch([7, 12, 39, 40 + BINS])  # 39 and 296 sit just outside the angle ids
    logits = jax.random.normal(jax.random.key(1), (1, 5, VOCAB))
    wide = loss.smoothed_angle_sum(logits, tokens, mask, jnp.asarray(ANGLE_IDS), jnp.asarray(loss.circular_kernel(BINS, 8.0)))
    assert float(wide) == pytest.approx(float(loss.token_sums(logits, tokens, mask)["loss_sum"]), rel=1e-6)


def test_a_near_miss_across_the_wrap_costs_less_than_a_far_one():
    tokens, mask = _batch([40 + 0])
    kernel, ids = jnp.asarray(loss.circular_kernel(BINS, 8.0)), jnp.asarray(ANGLE_IDS)
    cost = {peak: float(loss.smoothed_angle_sum(_peaked_logits([40 + peak]), tokens, mask, ids, kernel))
            for peak in (0, 3, 253, 128)}
    assert cost[3] == pytest.approx(cost[253], rel=1e-6)
    assert cost[0] < cost[3] < cost[128]
    plain = {peak: float(loss.token_sums(_peaked_logits([40 + peak]), tokens, mask)["loss_sum"]) for peak in (3, 128)}
    assert plain[3] == pytest.approx(plain[128], rel=1e-6)  # what the plain cross-entropy cannot tell apart


def test_only_counted_targets_add():
    tokens, mask = _batch([40 + 5, 40 + 9])
    logits = jax.random.normal(jax.random.key(2), (1, 3, VOCAB))
    kernel, ids = jnp.asarray(loss.circular_kernel(BINS, 8.0)), jnp.asarray(ANGLE_IDS)
    both = float(loss.smoothed_angle_sum(logits, tokens, mask, ids, kernel))
    first = float(loss.smoothed_angle_sum(logits, tokens, mask.at[0, 2].set(False), ids, kernel))
    second = float(loss.smoothed_angle_sum(logits, tokens, mask.at[0, 1].set(False), ids, kernel))
    assert both == pytest.approx(first + second, rel=1e-6) and 0 < first < both


def test_the_step_refuses_smoothing_without_angle_tokens():
    from kosmos_jax.train import step
    with pytest.raises(ValueError, match="angle tokens"):
        step.make_train_step(None, None, None, None, auxiliary=AuxiliaryLosses(angle_smoothing=8.0),
                             angle_ids=np.zeros((0,), np.int32))


def test_the_angle_tokens_are_found_in_bin_order():
    from kosmos_jax.models.value_embeddings import angle_token_ids
    shuffled = [f"a_{k}" for k in np.random.default_rng(0).permutation(BINS)]
    pieces = ["<s>", "x_3", *shuffled, "Grasp"]
    ids = angle_token_ids(pieces)
    assert [pieces[i] for i in ids] == [f"a_{k}" for k in range(BINS)]
    assert angle_token_ids(["<s>", "x_3", "a", "_12"]).shape == (0,)  # digits: no angle tokens


def test_the_patch_angle_loss_reads_the_grasp_patch_and_its_angle_bin():
    from kosmos_jax import geometry
    side, width = 4, 8
    rows = jax.random.normal(jax.random.key(3), (BINS, width))
    theta = 0.4
    tokens = np.zeros((1, 1 + side * side, width), np.float32)
    cell = 2 * side + 1  # the grasp below sits in column 1, row 2 of the 4x4 grid
    tokens[0, 1 + cell] = 5.0 * np.asarray(rows[int(geometry.encode_angle(theta))])
    grasp = jnp.asarray([[1.5 * 28, 2.5 * 28, 20.0, 10.0, theta]], jnp.float32)  # a 112 px image
    mask = jnp.asarray([[False, True, True, False]])
    at_patch = float(loss.patch_angle_sum(jnp.asarray(tokens), rows, grasp, 112, mask))
    elsewhere = float(loss.patch_angle_sum(jnp.asarray(np.roll(tokens, 1, axis=1)), rows, grasp, 112, mask))
    turned = float(loss.patch_angle_sum(jnp.asarray(tokens), rows, grasp.at[0, 4].set(theta + 1.2), 112, mask))
    assert at_patch < elsewhere and at_patch < turned
    uniform = float(loss.patch_angle_sum(jnp.zeros_like(tokens), rows, grasp, 112, mask))
    assert uniform == pytest.approx(2 * np.log(BINS), rel=1e-6)  # two loss tokens, a uniform guess each
    assert float(loss.patch_angle_sum(jnp.zeros_like(tokens), rows, grasp.at[0, 0].set(jnp.nan), 112, mask)) == 0.0


def test_the_tower_angle_loss_reads_the_grasp_patch_as_twice_its_angle():
    side, width = 4, 8
    directions = loss.tower_angle_directions(width)
    np.testing.assert_allclose(directions.T @ directions, np.eye(2), atol=1e-6)  # an orthonormal pair
    theta = 0.4
    features = np.zeros((1, 1 + side * side, width), np.float32)
    cell = 2 * side + 1  # column 1, row 2 of the 4x4 grid, as above
    features[0, 1 + cell] = directions @ (loss.TOWER_ANGLE_RADIUS * np.array([np.cos(2 * theta), np.sin(2 * theta)]))
    grasp = jnp.asarray([[1.5 * 28, 2.5 * 28, 20.0, 10.0, theta]], jnp.float32)
    mask = jnp.asarray([[False, True, True, False]])
    exact = float(loss.tower_angle_sum(jnp.asarray(features), grasp, 112, mask))
    assert exact == pytest.approx(0.0, abs=1e-6)
    half_turn = float(loss.tower_angle_sum(jnp.asarray(features), grasp.at[0, 4].add(np.pi), 112, mask))
    assert half_turn == pytest.approx(0.0, abs=1e-5)  # a grasp turned half a turn is the same grasp
    quarter = float(loss.tower_angle_sum(jnp.asarray(features), grasp.at[0, 4].add(np.pi / 2), 112, mask))
    assert quarter == pytest.approx(2 * (2 * loss.TOWER_ANGLE_RADIUS) ** 2, rel=1e-5)  # opposite on the circle, two tokens
    elsewhere = float(loss.tower_angle_sum(jnp.asarray(np.roll(features, 1, axis=1)), grasp, 112, mask))
    assert elsewhere == pytest.approx(2 * loss.TOWER_ANGLE_RADIUS ** 2, rel=1e-5)  # a zero read at the grasp's patch
    assert float(loss.tower_angle_sum(jnp.asarray(features), grasp.at[0, 0].set(jnp.nan), 112, mask)) == 0.0


def test_the_slot_angle_loss_reads_every_slot_at_unit_norm_as_twice_the_angle():
    width, theta = 8, 0.4
    directions = loss.tower_angle_directions(width)
    on_circle = directions @ (loss.TOWER_ANGLE_RADIUS * np.array([np.cos(2 * theta), np.sin(2 * theta)]))
    rest = np.linalg.qr(np.c_[directions, np.random.default_rng(1).normal(size=(width, 1))])[0][:, 2]
    unit = on_circle + rest * np.sqrt(1 - loss.TOWER_ANGLE_RADIUS ** 2)  # norm 1, reads the target exactly
    slots = np.stack([unit, 7.0 * unit, -unit])[None].astype(np.float32)  # [1, 3 slots, width]
    grasp = jnp.asarray([[40.0, 50.0, 20.0, 10.0, theta]], jnp.float32)
    mask = jnp.asarray([[False, True, True, False]])  # 2 loss tokens weigh the example
    # the first two slots read the target whatever their scale; the third reads its opposite
    expected = 2 * (2 * loss.TOWER_ANGLE_RADIUS) ** 2 / 3  # 2 loss tokens x the mean over 3 slots
    assert float(loss.slot_angle_sum(jnp.asarray(slots), grasp, mask)) == pytest.approx(expected, rel=1e-5)
    assert float(loss.slot_angle_sum(jnp.asarray(slots[:, :2]), grasp, mask)) == pytest.approx(0.0, abs=1e-6)
    assert float(loss.slot_angle_sum(jnp.asarray(slots), grasp.at[0, 4].set(jnp.nan), mask)) == 0.0
