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
cpu_pretrained: cpu_demo's mixes, data and fold, KOSMOS-E fine-tuned for 800 steps at make demo's fine-tune rate
(3e-4) from a grounding pretraining run on every instruction kind, single photos and mosaics (the shipped
start, results/pretrain/demo_photos1200, knows NON's words only). Make that run first (19 minutes on 2
quiet cores, results/pretrain/README.md, "More scenes a chunk, fewer examples of each"):

    python -m kosmos_jax.train --config=configs/pretrain.py:demo_stream_instruct --workdir=runs/pretrain/stream_wide1500 \
        --config.train.steps=1500 --config.data.stream.photos=256 --config.data.stream.examples=4096

Fold 0 of its four arms took 712 to 820 s an arm, 3,037 s in all, on 2 quiet cores (results/table2_pretrained,
beside cpu_demo rerun with today's recipe, 3,016 s).
cpu_grounded: cpu_pretrained from the committed grounding start that make demo fine-tunes (results/pretrain/
grounding6000: the same pretraining for 6,000 steps with the tower asked for the object's category), nothing to
make first.
paper: configs/kosmos_e.py:paper (Cornell with KOSMOS-E's annotations, KOSMOS-2 initialisation:
--config.init_from), both protocols, image-wise, every fold.

The cpu_demo records in results/ were made before configs/kosmos_e.py:demo gained the tower- and
slot-angle losses (2026-11-26) and before fold records kept their recipe: --records_from cannot
tell them from today's recipe, so a rerun must not carry them in (today's recipe's records:
results/table2_pretrained/scratch_folds).
"""

from kosmos_jax.experiments.spec import GROUNDING6000_START, arm, experiment, load_config

MIXES = ("non", "single", "multi", "all")
CPU_STEPS = 200
VARIANTS = ("cpu", "cpu_demo", "cpu_pretrained", "cpu_grounded", "paper")
STREAM_START = "runs/pretrain/stream_wide1500"  # made by the command of the docstring
STARTS = {"cpu_pretrained": STREAM_START, "cpu_grounded": GROUNDING6000_START}  # the starts their records came from


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
    if variant in STARTS:
        # the start's model (its connector reads the instruction) and its tokenizer, which knows every kind's words;
        # make demo's fine-tune rate, chosen on validation for the shipped start
        peak_lr = load_config("configs/kosmos_e.py:demo_photos_finetune").optimizer.peak_lr
        arms = {mix: arm("configs/kosmos_e.py:demo_finetune", {
            "data.build.kinds": mix, "data.build.augmentations": 4, "data.build.max_length": 128,
            "model.connector_instruction": True, "optimizer.peak_lr": peak_lr, "init_from": STARTS[variant]})
            for mix in MIXES}
        return experiment("table2", arms, schemes="image", protocols="honest", folds="0")
    arms = {mix: arm("configs/kosmos_e.py:paper", {"data.build.kinds": mix}) for mix in MIXES}
    return experiment("table2", arms, schemes="image", protocols="honest,paper")
