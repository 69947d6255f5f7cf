"""Table V: the loss on the target tokens only (the answer and </s>) vs on every text token after
the image (loss_on "instruction"), each with the angle as a 256-bin code or in radians.

    python -m kosmos_jax.experiments --config=configs/experiments/table5.py:cpu --workdir=runs/table5

cpu: synthetic scenes (300 photos, 4 augmentations a training photo), every instruction kind (so
the instruction text varies and a loss on it means something), max_length 144, KOSMOS-E from
configs/kosmos_e.py:demo_kosmos2 trained from scratch for 300 steps (a 300-step fold of Table I took 383
to 569 s on 2 shared cores; this config has not been run here); honest protocol, image-wise folds
0, 1 and 2 of 5 by default (12 folds). paper: configs/kosmos_e.py:paper (Cornell, every instruction kind, KOSMOS-2
initialisation: --config.init_from), both protocols, image-wise, every fold.
"""

from kosmos_jax.experiments.spec import arm, experiment

LOSSES = {"target": "target", "all": "instruction"}
ANGLES = {"code": True, "radians": False}
CPU_STEPS = 300
VARIANTS = ("cpu", "paper")


def arms_of(config: str, changes: dict) -> dict:
    return {f"{loss}_{angle}": arm(config, {"data.build.loss_on": loss_on, "data.build.angle_code": code, **changes})
            for loss, loss_on in LOSSES.items() for angle, code in ANGLES.items()}


def get_config(arg: str | None = None):
    variant = arg or "cpu"
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} of configs/experiments/table5.py; expected one of {VARIANTS}")
    if variant == "cpu":
        arms = arms_of("configs/kosmos_e.py:demo_kosmos2", {"data.build.kinds": "all", "data.build.augmentations": 4,
                                                    "data.build.max_length": 144, "train.steps": CPU_STEPS})
        return experiment("table5", arms, schemes="image", protocols="honest", folds="0,1,2")
    return experiment("table5", arms_of("configs/kosmos_e.py:paper", {}), schemes="image", protocols="honest,paper")
