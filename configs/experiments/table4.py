"""Table IV: individual outputs (the centre and the angle asked apart, combined into one grasp) vs
joint outputs (one answer holds the whole grasp), each with the angle as a 256-bin code or in radians.

    python -m kosmos_jax.experiments --config=configs/experiments/table4.py:cpu --workdir=runs/table4

cpu: synthetic scenes (the demo's 300 photos and 16 augmentations), instruction kind NON,
KOSMOS-E from configs/kosmos_e.py:demo_kosmos2 trained from scratch for 300 steps (a 300-step fold of Table I took
383 to 569 s on 2 shared cores; this config has not been run here); honest protocol, image-wise
folds 0, 1 and 2 of 5 by default (12 folds). cpu_demo: the same four arms with the demo recipe
(configs/kosmos_e.py:demo: photo-centre training crops, value tokens, the pointing connector; 800
steps), honest protocol, image-wise fold 0; its individual_code arm is the demo itself, and
joint_radians alone takes sequences of 96 tokens (its answers need 89, the demo's length is 88). paper:
configs/kosmos_e.py:paper (Cornell, every instruction kind, KOSMOS-2 initialisation:
--config.init_from), both protocols, image-wise, every fold.

The cpu_demo records in results/ were made before configs/kosmos_e.py:demo gained the tower- and
slot-angle losses (2026-11-26) and before fold records kept their recipe: --records_from cannot
tell them from today's recipe, so a rerun must not carry them in (today's recipe's records:
results/table4_demo/rerun_2026-11-29).
"""

from kosmos_jax.experiments.spec import arm, experiment

OUTPUTS = {"individual": True, "joint": False}
ANGLES = {"code": True, "radians": False}
CPU_STEPS = 300
DEMO_JOINT_RADIANS_LENGTH = 96
VARIANTS = ("cpu", "cpu_demo", "paper")


def arms_of(config: str, changes: dict) -> dict:
    return {f"{output}_{angle}": arm(config, {"data.build.individual": individual, "data.build.angle_code": code,
                                              **changes})
            for output, individual in OUTPUTS.items() for angle, code in ANGLES.items()}


def get_config(arg: str | None = None):
    variant = arg or "cpu"
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} of configs/experiments/table4.py; expected one of {VARIANTS}")
    if variant == "cpu":
        arms = arms_of("configs/kosmos_e.py:demo_kosmos2", {"data.build.kinds": "non", "train.steps": CPU_STEPS})
        return experiment("table4", arms, schemes="image", protocols="honest", folds="0,1,2")
    if variant == "cpu_demo":
        arms = arms_of("configs/kosmos_e.py:demo", {"data.build.kinds": "non"})
        # a joint answer in radians ("x_98,y_178 ... a_-0.41") is one token over the demo's 88
        arms["joint_radians"].overrides.data.build.max_length = DEMO_JOINT_RADIANS_LENGTH
        return experiment("table4", arms, schemes="image", protocols="honest", folds="0")
    return experiment("table4", arms_of("configs/kosmos_e.py:paper", {}), schemes="image", protocols="honest,paper")
