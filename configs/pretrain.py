"""Grounding pretraining of the demo model on synthetic scenes (issue 22): every instruction kind,
single photos and four-photo mosaics, on scenes of seeds no test set uses.

    python -m kosmos_jax.train --config=configs/pretrain.py:demo --workdir=runs/pretrain/demo
    python -m kosmos_jax.train --config=configs/pretrain.py:tiny --workdir=runs/pretrain/tiny

Then fine-tune from it (config.init_from takes the run's workdir: its newest checkpoint's
parameters, its model and its tokenizer):

    python -m kosmos_jax.train --config=configs/kosmos_e.py:demo_finetune --workdir=runs/finetune \\
        --config.init_from=runs/pretrain/demo

Variants:
  demo  the model of configs/kosmos_e.py:demo on 2,000 scenes of seed 1000 (two augmented views a
        photo, about 120,000 examples of 15 kinds), validation scored during the run
  demo_stream  the same model on scenes made on the fly (train/scene_stream.py): chunks of 64 new
        photos of seeds 10,000, 10,001, ..., never stored, never repeated; 600 stored scenes of seed
        1000 give the tokenizer, validation and test
  demo_stream_ground  demo_stream with slots that are the patches (pointing_target "identity") and the
        decoder asked, at each answer token, which slot holds the named object's grasp (answer_pointing_loss);
        no slot-angle loss (it asks every slot for the target's angle). Refuted on validation: its
        answers stop following the photo and its pointer picks a mosaic's named photo at chance
        (results/pretrain/README.md, "Slots that are the patches")
  demo_stream_instruct  demo_stream whose connector's latent queries also read the instruction
        (model.connector_instruction), so its pointing loss, which asks every query for the target grasp,
        asks it for the object the instruction names. On validation: 91% of mosaic answers in the quadrant
        that position words name (43% without), object words still at chance at 1,500 steps
        (results/pretrain/README.md, "A connector that reads the instruction")
  tiny  transformers' test-sized model on 16 scenes of seed 1000, seconds a step (the tests use it)
  tiny_stream  tiny on chunks of 8 scenes made on the fly

Seeds: the demo trains and tests on seed 0's scenes, scores the unseen seed 1 and validates
recipes on seed 7 (results/angle_study); pretraining scenes use seed 1000 and up, so none of
them is a test or validation photo of any of those.
"""

import importlib.util
import pathlib

import ml_collections


def _sibling(name: str):
    """A config file beside this one, loaded by path (config files are not a package)."""
    spec = importlib.util.spec_from_file_location(f"_config_{name}", pathlib.Path(__file__).with_name(f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


kosmos_e = _sibling("kosmos_e")

VARIANTS = ("demo", "demo_stream", "demo_stream_ground", "demo_stream_instruct", "tiny", "tiny_stream")
STREAM_SEED = 10_000  # the first seed of scenes made on the fly (the *_stream variants): chunk k has seed 10,000 + k
PRETRAIN_SEED = 1000  # the scenes' seed: no test or validation set of the project uses it


def get_config(arg: str | None = None) -> ml_collections.ConfigDict:
    variant = arg or "demo"
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} of configs/pretrain.py; expected one of {VARIANTS}")
    base = kosmos_e.get_config("demo" if variant.startswith("demo") else "tiny")
    base.variant = f"pretrain_{variant}"
    if variant.startswith("demo"):
        # 50 folds: the test fold (40 photos) and validation (2%) stay small enough to decode at the end
        base.data = kosmos_e.data_config(top=dict(synthetic_photos=2000, synthetic_seed=PRETRAIN_SEED),
                                         augmentations=2, kinds="all", train_crop="image_centre",
                                         numbers="values", max_length=120, folds=50, validation_fraction=0.02)
        base.optimizer = kosmos_e.optimizer_config(peak_lr=1e-3, warmup_steps=200)
        base.train = kosmos_e.train_config(steps=6000, batch_size=32, log_every=10, eval_every=500,
                                           eval_batches=8, checkpoint_every=100, pointing_loss=1.0,
                                           tower_angle_loss=4.0, slot_angle_loss=1.0)
    else:
        base.data = kosmos_e.data_config(top=dict(synthetic_photos=16, synthetic_seed=PRETRAIN_SEED),
                                         augmentations=2, kinds="all", max_length=128, text_pieces=300)
    if variant.startswith("demo_stream"):
        base.data.synthetic_photos = 600
        base.data.build.update(folds=15, validation_fraction=0.07)  # 40 test photos, 39 validation
        base.data.stream.update(photos=64, seed=STREAM_SEED)
    if variant == "demo_stream_instruct":
        base.model.connector_instruction = True
    if variant == "demo_stream_ground":
        base.train.update(pointing_target="identity", slot_angle_loss=0.0, answer_pointing_loss=1.0)
    elif variant == "tiny_stream":
        base.data.stream.update(photos=8, seed=STREAM_SEED)
    return base
