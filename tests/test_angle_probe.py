"""experiments.angle_probe: a ridge readout of twice the grasp angle, scored within 30 degrees."""

import numpy as np
import pytest

from kosmos_jax.experiments import angle_probe as probe


def test_a_readout_of_features_that_hold_the_angle_finds_it_and_noise_does_not():
    rng = np.random.default_rng(0)
    angles = rng.uniform(-np.pi / 2, np.pi / 2, 2000)
    noise = rng.normal(size=(2000, 6))
    holding = np.c_[3 * probe.doubled(angles) + 0.1 * noise[:, :2], noise]
    read = probe.ridge_readout(holding[:1500], angles[:1500], ridge=1e-3)
    assert probe.within(read(holding[1500:]), angles[1500:]) > 99
    blind = probe.ridge_readout(noise[:1500], angles[:1500], ridge=1e-3)
    assert 20 < probe.within(blind(noise[1500:]), angles[1500:]) < 50  # about a third: 60 of 180 degrees


def test_within_counts_a_half_turn_as_the_same_grasp_and_a_right_angle_as_a_miss():
    angles = np.array([0.1, 0.1, 0.1])
    answers = np.array([0.1 + np.pi, 0.1 + np.radians(29), 0.1 + np.pi / 2])
    assert probe.within(probe.doubled(answers), angles) == pytest.approx(200 / 3, abs=0.01)
