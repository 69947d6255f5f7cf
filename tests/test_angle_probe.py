"""diagnostics.angle_probe: a ridge readout of twice the grasp angle, scored within 30 degrees."""

import numpy as np
import pytest

from kosmos_jax.diagnostics import angle_probe as probe


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


def test_the_explained_share_is_the_variance_the_explanation_reproduces():
    rng = np.random.default_rng(0)
    angles = rng.uniform(-np.pi / 2, np.pi / 2, 20000)
    # one column that is cos 2theta (variance 1/2), three of unit-variance noise: 1/2 of 7/2 explained
    features = np.c_[probe.doubled(angles)[:, :1], rng.normal(size=(20000, 3))]
    assert probe.explained_share(features, probe.doubled(angles)) == pytest.approx(1 / 7, abs=0.01)
    assert probe.explained_share(features[:, 1:], probe.doubled(angles)) == pytest.approx(0.0, abs=0.002)
    assert probe.explained_share(5 * features[:, :1] + 2, probe.doubled(angles)) == pytest.approx(1.0, abs=1e-9)


def test_model_readouts_score_each_place_and_the_decoders_own_answer():
    rng = np.random.default_rng(1)
    angles = rng.uniform(-np.pi / 2, np.pi / 2, 600)
    cells = rng.integers(0, 4, 600)
    holding, blind = np.c_[probe.doubled(angles), np.eye(4)[cells]], np.eye(4)[cells] + 0.01 * rng.normal(size=(600, 4))
    views = {"tower": holding, "slots": blind, "answer": angles + np.radians(40) * (np.arange(600) % 2),
             "angle": angles, "cell": cells}
    train, test = ({key: value[part] for key, value in views.items()} for part in (slice(0, 400), slice(400, None)))
    out = probe.model_readouts(train, test, ridge=1e-3)
    assert set(out) == {"tower", "slots", "answer"}  # no decoder place given, none scored
    assert out["tower"]["test"] == 100 and out["tower"]["angle_share"] > 0.4 and out["slots"]["angle_share"] < 0.05
    assert out["slots"]["cell_share"] > 0.99 and out["slots"]["test"] < 60
    assert out["answer"]["test"] == 50.0 and out["answer"]["distinct_test"] == 200  # every other answer 40 degrees off
