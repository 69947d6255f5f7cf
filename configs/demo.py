"""The demo of `make demo`: KOSMOS-E trained on synthetic scenes, beside the no-learning baselines.

    python -m kosmos_jax.demo --config=configs/demo.py             # train the demo model, then the tables
    python -m kosmos_jax.demo --config=configs/demo.py:tiny        # a laptop smoke run (tiny model, 24 photos)
    python -m kosmos_jax.demo --config=configs/demo.py --config.train_config=   # baselines only
    python -m kosmos_jax.demo --config=configs/demo.py --config.train_config=configs/kosmos_e.py:demo_photos \
        --config.init_from=                                        # the demo model from scratch (NON only)
    python -m kosmos_jax.demo --config=configs/demo.py --config.train_config=configs/kosmos_e.py:demo_photos_finetune \
        --config.init_from=results/pretrain/demo_photos1200 --config.out=demo_nonstart   # make demo before 2026-11-30
    python -m kosmos_jax.demo --config=configs/demo.py --config.init_from=results/pretrain/grounding6000 \
        --config.out=demo_g6000                                    # make demo from 2026-11-30 to 2026-12-01
    python -m kosmos_jax.demo --config=configs/demo.py --config.init_from=results/pretrain/grounding10000 \
        --config.out=demo_g10000                                   # make demo on 2026-12-01
    python -m kosmos_jax.demo --config=configs/demo.py --config.train_config=configs/kosmos_e.py:demo_grounded \
        --config.init_from=results/pretrain/grounding14000 --config.steps=800 --config.out=demo_g14000
                                                                   # make demo from 2026-12-04 to 2026-12-06
    python -m kosmos_jax.demo --config=configs/demo.py --config.init_from=results/pretrain/grounding16400 \
        --config.peak_lr=3e-4 --config.out=demo_g16400             # make demo on 2026-12-06
    python -m kosmos_jax.demo --config=configs/demo.py --config.train_config=configs/kosmos_e.py:demo_grounded224 \
        --config.out=demo_g21200_random                            # make demo on 2026-12-07 (morning)
    python -m kosmos_jax.demo --config=configs/demo.py --config.init_from=results/pretrain/grounding21200 \
        --config.out=demo_g21200                                   # make demo on 2026-12-07 (afternoon)
    python -m kosmos_jax.demo --config=configs/demo.py --config.train_seed=1 --config.out=demo_seed1   # another seed
"""

import ml_collections

from kosmos_jax.experiments.spec import DEMO_START


def get_config(arg: str | None = None) -> ml_collections.ConfigDict:
    tiny = arg == "tiny"
    config = ml_collections.ConfigDict()
    config.out = "demo_out"  # relative to the repository root; the run is OUT/run, its data OUT/datasets
    config.train_config = "configs/kosmos_e.py:tiny" if tiny else "configs/kosmos_e.py:demo_grounded224_consensus"  # "": no training
    # 0: the training config's own train.steps (demo_grounded224_consensus's 400: its 800 read more on validation mosaics, but
    # at 224 px they take make demo past its 15 minutes; results/finer_grid/README.md)
    config.steps = 0
    config.train_seed = -1  # -1: the training config's own train.seed; another seed wants its own config.out
    config.peak_lr = 0.0  # 0: the training config's own optimizer.peak_lr; another rate wants its own config.out
    # a run's workdir or an exported folder to start from (relative to the repository root), given to the
    # training config as its config.init_from; "": from scratch. The default is the committed grounding start,
    # pretrained on scenes made on the fly from seeds no demo test or validation set uses (results/pretrain/README.md,
    # results/finer_grid/README.md)
    config.init_from = "" if tiny else DEMO_START
    config.photos = 24 if tiny else 60  # synthetic photos of the no-learning table (object-wise needs >= 5 objects)
    config.seed = 0
    # the trained model on scenes it never saw (another seed): NON on each, multi-object kinds on mosaics
    config.fresh_photos = 20 if tiny else 40  # 0: not scored; mosaics need photos of at least 4 objects
    config.fresh_seed = 1  # must differ from the training scenes' seed (0)
    config.fresh_kinds = "non,multi"
    config.cornell = ""  # a Cornell-format folder; "" = ../shared/data/cornell when it exists
    config.folds = 5
    return config
