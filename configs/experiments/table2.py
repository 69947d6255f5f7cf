"""Table II: instruction following. KOSMOS-E trained on the NON, SINGLE, MULTI or ALL mix of
instruction kinds (the build's `kinds`: "non", "single", "multi", "all"), scored per kind and per
scene (single object / multi-object mosaic).

    python -m kosmos_jax.experiments --config=configs/experiments/table2.py:cpu --workdir=runs/table2

Each arm is scored on its own fold's test split, whose instructions are the kinds it trained on
(the build makes both splits from one `kinds`): the table's per-kind columns compare arms on the
kinds they share. The no-learning rows come once per distinct test set.

cpu: synthetic scenes (300 photos, 4 augmentations a training photo), KOSMOS-E from
configs/kosmos_e.py:demo_kosmos2 trained from scratch for 200 steps, max_length 144 (ALL's longest example on synthetic scenes is
about 120 tokens); honest protocol, image-wise folds 0, 1 and 2 of 5 by default (12 folds). Fold 0 of
the four arms took 514 to 775 s a fold, 2,536 s in all, on 2 shared cores (results/table2).
cpu_demo: the same four mixes with the demo recipe (configs/kosmos_e.py:demo: photo-centre training crops,
value tokens, the pointing connector; 800 steps), 4 augmentations a training photo as cpu, max_length 128
(value tokens make answers shorter than digits); honest protocol, image-wise fold 0 (results/table2_demo:
757 to 885 s an arm on 2 cores, 2026-11-25).
paper: configs/kosmos_e.py:paper (Cornell with KOSMOS-E's annotations, KOSMOS-2 initialisation:
--config.init_from), both protocols, image-wise, every fold.

The cpu_demo records in results/ were made before configs/kosmos_e.py:demo gained the tower- and
slot-angle losses (2026-11-26) and before fold records kept their recipe: --records_from cannot
tell them from today's recipe, so a rerun must not carry them in.
"""

from kosmos_jax.experiments.spec import arm, experiment

MIXES = ("non", "single", "multi", "all")
CPU_STEPS = 200
VARIANTS = ("cpu", "cpu_demo", "paper")


def get_config(arg: str | None = None):
    variant = arg or "cpu"
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} of configs/experiments/table2.py; expected one of {VARIANTS}")
    if variant == "cpu":
        arms = {mix: arm("configs/kosmos_e.py:demo_kosmos2", {"data.build.kinds": mix, "data.build.augmentations": 4,
                                                      "data.build.max_length": 144, "train.steps": CPU_STEPS})
                for mix in MIXES}
        return experiment("table2", arms, schemes="image", protocols="honest", folds="0,1,2")
    if variant == "cpu_demo":
        arms = {mix: arm("configs/kosmos_e.py:demo", {"data.build.kinds": mix, "data.build.augmentations": 4,
                                                      "data.build.max_length": 128}) for mix in MIXES}
        return experiment("table2", arms, schemes="image", protocols="honest", folds="0")
    arms = {mix: arm("configs/kosmos_e.py:paper", {"data.build.kinds": mix}) for mix in MIXES}
    return experiment("table2", arms, schemes="image", protocols="honest,paper")
