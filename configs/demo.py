"""The demo of `make demo`: no-learning baselines on synthetic data (and Cornell when present).

    python -m kosmos_jax.demo --config=configs/demo.py             # 60 synthetic photos
    python -m kosmos_jax.demo --config=configs/demo.py:tiny        # a laptop smoke run
    python -m kosmos_jax.demo --config=configs/demo.py --config.photos=200 --config.seed=1
"""

import ml_collections


def get_config(arg: str | None = None) -> ml_collections.ConfigDict:
    config = ml_collections.ConfigDict()
    config.out = "demo_out"  # relative to the repository root
    config.photos = 24 if arg == "tiny" else 60  # synthetic photos to make (object-wise needs >= 5 objects)
    config.seed = 0
    config.cornell = ""  # a Cornell-format folder; "" = ../shared/data/cornell when it exists
    config.folds = 5
    return config
