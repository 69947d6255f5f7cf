"""The train step's auxiliary-loss settings: read from config.train once, validated on construction."""

import dataclasses

import ml_collections
import pytest

from kosmos_jax.experiments.spec import load_config
from kosmos_jax.train.auxiliary import AuxiliaryLosses


def test_a_config_sets_what_it_names_and_the_rest_keep_their_defaults():
    train = ml_collections.ConfigDict(dict(steps=10, pointing_loss=1.0, tower_angle_loss=4.0, pointing_target="bilinear"))
    settings = AuxiliaryLosses.from_config(train)
    assert settings == AuxiliaryLosses(pointing_loss=1.0, tower_angle_loss=4.0, pointing_target="bilinear")
    assert settings.weights() == {"pointing": 1.0, "tower_angle": 4.0}
    assert AuxiliaryLosses.from_config({"steps": 10}) == AuxiliaryLosses()


def test_the_demo_config_names_every_setting():
    train = load_config("configs/kosmos_e.py:demo").train
    assert {f.name for f in dataclasses.fields(AuxiliaryLosses)} <= set(train.keys())
    assert AuxiliaryLosses.from_config(train).weights() == {"pointing": 1.0, "tower_angle": 4.0, "slot_angle": 1.0}


def test_angle_smoothing_is_not_a_weight_and_smoothing_alone_adds_no_loss():
    assert AuxiliaryLosses(angle_smoothing=8.0).weights() == {}


@pytest.mark.parametrize("bad, match", [(dict(pointing_target="nearest"), "pointing_target"),
                                        (dict(slot_angle_loss=-1.0), "slot_angle_loss"),
                                        (dict(pointing_queries=-2), "pointing_queries")])
def test_bad_settings_are_refused_by_name(bad, match):
    with pytest.raises(ValueError, match=match):
        AuxiliaryLosses(**bad)
