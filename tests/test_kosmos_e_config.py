"""configs/kosmos_e.py: every variant loads; demo_photos, demo_photos_finetune, demo_grounded, demo_grounded224,
demo_grounded224_consensus and demo_gpu change only what they say."""

import pytest

from kosmos_jax.experiments.spec import config_module


@pytest.fixture(scope="module")
def kosmos_e():
    return config_module("configs/kosmos_e.py")


def test_every_variant_loads_under_its_own_name_and_an_unknown_one_is_refused(kosmos_e):
    for variant in kosmos_e.VARIANTS:
        assert kosmos_e.get_config(variant).variant == variant
    with pytest.raises(ValueError, match="unknown variant 'demo_tpu'"):
        kosmos_e.get_config("demo_tpu")


def test_demo_gpu_is_the_demo_on_more_photos_for_more_steps(kosmos_e):
    demo, gpu = kosmos_e.get_config("demo").to_dict(), kosmos_e.get_config("demo_gpu").to_dict()
    assert (gpu["data"]["synthetic_photos"], gpu["train"]["steps"]) == (1200, 2400)
    assert gpu["train"]["steps"] % gpu["train"]["checkpoint_every"] == 0
    for changed in (("data", "synthetic_photos"), ("train", "steps"), ("train", "eval_every"),
                    ("train", "checkpoint_every"), ("variant",)):
        for config in (demo, gpu):
            *parents, leaf = changed
            (config[parents[0]] if parents else config).pop(leaf)
    assert gpu == demo  # everything else is the demo's own: its build, model, optimiser, losses, decoding


def test_demo_photos_is_the_demo_on_four_times_the_photos_with_a_quarter_of_the_views_each(kosmos_e):
    demo, photos = kosmos_e.get_config("demo").to_dict(), kosmos_e.get_config("demo_photos").to_dict()
    assert photos["data"]["synthetic_photos"] * photos["data"]["build"]["augmentations"] == \
        demo["data"]["synthetic_photos"] * demo["data"]["build"]["augmentations"] == 4800
    assert photos["data"]["synthetic_photos"] == 1200
    for config in (demo, photos):
        config.pop("variant"), config["data"].pop("synthetic_photos"), config["data"]["build"].pop("augmentations")
    assert photos == demo


def test_demo_photos_finetune_is_demo_photos_from_a_start_at_a_lower_learning_rate(kosmos_e):
    photos, tune = kosmos_e.get_config("demo_photos").to_dict(), kosmos_e.get_config("demo_photos_finetune").to_dict()
    assert tune["require_init"] and not photos["require_init"]
    assert tune["optimizer"]["peak_lr"] == kosmos_e.FINETUNE_PEAK_LR < photos["optimizer"]["peak_lr"]
    assert photos["model"]["value_token_code"] > 0 and tune["model"]["value_token_code"] == 0  # loaded, not made
    for config in (photos, tune):
        config.pop("variant"), config.pop("require_init"), config["optimizer"].pop("peak_lr")
        config["model"].pop("value_token_code")
    assert tune == photos


def test_demo_grounded_is_the_fine_tune_with_the_instruction_reading_connector_on_mosaics_too(kosmos_e):
    tune, grounded = kosmos_e.get_config("demo_photos_finetune").to_dict(), kosmos_e.get_config("demo_grounded").to_dict()
    assert grounded["require_init"] and grounded["model"]["connector_instruction"]
    assert (grounded["data"]["build"]["kinds"], grounded["data"]["build"]["max_length"]) == ("non,multi", 128)
    assert grounded["train"]["steps"] == grounded["train"]["eval_every"] == tune["train"]["steps"] // 2
    for config in (tune, grounded):
        config.pop("variant"), config["model"].pop("connector_instruction")
        config["data"]["build"].pop("kinds"), config["data"]["build"].pop("max_length")
        config["train"].pop("steps"), config["train"].pop("eval_every")
    assert grounded == tune


def test_demo_grounded224_is_demo_grounded_on_a_16_by_16_grid_at_half_its_rate_and_make_demo_trains_it_for_its_own_steps(kosmos_e):
    grounded, finer = kosmos_e.get_config("demo_grounded").to_dict(), kosmos_e.get_config("demo_grounded224").to_dict()
    assert (grounded["model"]["vision"]["image_size"], finer["model"]["vision"]["image_size"]) == (112, 224)
    assert finer["model"]["vision"]["image_size"] // finer["model"]["vision"]["patch_size"] == 16
    assert finer["optimizer"]["peak_lr"] == grounded["optimizer"]["peak_lr"] / 2 == 1.5e-4
    for config in (grounded, finer):
        config.pop("variant"), config["model"]["vision"].pop("image_size"), config["optimizer"].pop("peak_lr")
    assert finer == grounded
    # make demo takes the training config's own steps (which config it trains, against its start's model:
    # tests/test_shipped_starts.py)
    demo = config_module("configs/demo.py")
    assert demo.get_config().steps == demo.get_config("tiny").steps == 0


def test_demo_grounded224_consensus_changes_only_the_target_grasp_and_is_what_make_demo_trains(kosmos_e):
    finer, consensus = kosmos_e.get_config("demo_grounded224").to_dict(), kosmos_e.get_config("demo_grounded224_consensus").to_dict()
    assert (finer["data"]["build"]["target_grasp"], consensus["data"]["build"]["target_grasp"]) == ("random", "consensus")
    for config in (finer, consensus):
        config.pop("variant"), config["data"]["build"].pop("target_grasp")
    assert consensus == finer
    assert config_module("configs/demo.py").get_config().train_config == "configs/kosmos_e.py:demo_grounded224_consensus"
