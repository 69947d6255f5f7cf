"""Table III: the grasp representation in the answer text: XYA, XYWHA, TLBRA, TLBRA-patch.

    python -m kosmos_jax.experiments --config=configs/experiments/table3.py:cpu --workdir=runs/table3

cpu: synthetic scenes (the demo's 300 photos and 16 augmentations), instruction kind NON,
KOSMOS-E from configs/kosmos_e.py:demo_kosmos2 trained from scratch for 300 steps (a 300-step fold of Table I took
383 to 569 s on 2 shared cores; this config has not been run here); honest protocol, image-wise
folds 0, 1 and 2 of 5 by default (12 folds). cpu_demo: the same four representations with the demo recipe
(configs/kosmos_e.py:demo: photo-centre training crops, value tokens, the pointing connector; 800
steps), honest protocol, image-wise fold 0; its xya arm is the demo itself (results/table3_demo). paper: configs/kosmos_e.py:paper (Cornell, every instruction kind,
KOSMOS-2 initialisation: --config.init_from), both protocols, image-wise, every fold.

The cpu_demo records in results/ were made before configs/kosmos_e.py:demo gained the tower- and
slot-angle losses (2026-11-26) and before fold records kept their recipe: --records_from cannot
tell them from today's recipe, so a rerun must not carry them in.
"""

from kosmos_jax.experiments.spec import arm, experiment

REPRESENTATIONS = ("xya", "xywha", "tlbra", "tlbra_patch")
CPU_STEPS = 300
VARIANTS = ("cpu", "cpu_demo", "paper")


def get_config(arg: str | None = None):
    variant = arg or "cpu"
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} of configs/experiments/table3.py; expected one of {VARIANTS}")
    if variant == "cpu":
        arms = {name: arm("configs/kosmos_e.py:demo_kosmos2", {"data.build.kinds": "non", "data.build.representation": name,
                                                       "train.steps": CPU_STEPS})
                for name in REPRESENTATIONS}
        return experiment("table3", arms, schemes="image", protocols="honest", folds="0,1,2")
    if variant == "cpu_demo":
        arms = {name: arm("configs/kosmos_e.py:demo", {"data.build.kinds": "non", "data.build.representation": name})
                for name in REPRESENTATIONS}
        return experiment("table3", arms, schemes="image", protocols="honest", folds="0")
    arms = {name: arm("configs/kosmos_e.py:paper", {"data.build.representation": name}) for name in REPRESENTATIONS}
    return experiment("table3", arms, schemes="image", protocols="honest,paper")
