"""Fig. 6: grasp accuracy against the amount of training data, image-wise and object-wise.

    python -m kosmos_jax.experiments --config=configs/experiments/data_size.py:cpu --workdir=runs/fig6

Two series of arms that differ only in their training data: "augmentations" (augmented views of
each training photo) and, on synthetic scenes, "photos" (how many scenes are drawn: more than
Cornell has). One arm sits on both lines. The runner writes WORKDIR/data_size.png (accuracy vs
training examples, log x, error bars the std over folds) and data_size.json; x is each run's
training-split example count as its build recorded it.

cpu: synthetic scenes, instruction kind NON, KOSMOS-E from configs/kosmos_e.py:demo_kosmos2 trained from
scratch for the same 200 steps in every arm, so the arms differ in data, not in compute: augmentations 2, 4, 8, 16 of 300 photos and
100, 300, 1000, 3000 photos of 4 augmentations (about 640 to 19,000 training examples); honest
protocol, image- and object-wise folds 0, 1 and 2 of 5 by default (42 folds). Three image-wise folds
took 546 to 1,015 s each on 2 shared cores (results/data_size).
cpu_demo: both series again with the demo recipe (configs/kosmos_e.py:demo: photo-centre training
crops, value tokens, the pointing connector), whose answers do depend on the photo: 100, 300 and
1,000 photos of 16 augmentations, and 4, 8 and 16 augmentations of 300 photos, 800 steps each (the
demo's own schedule; 300 photos of 16 is the demo), honest protocol, image- and object-wise fold 0
by default. About 11 to 15 minutes an arm on 2 cores.
cpu_pretrained: the "photos" series with `make demo`'s recipe until 2026-11-30, the committed start
results/pretrain/demo_photos1200 (pretrained on 1,200 photos of seed 1000, none of them a test photo)
fine-tuned for 800 steps (configs/kosmos_e.py:demo_photos_finetune) on 150, 300, 600 and 1,200 photos
of seed 0, 4 augmentations each (1,200 is the demo's own data); honest protocol, image-wise folds 0, 1
and 2 for the spread. About 10 minutes a fold on 2 quiet cores.
cpu_scratch: cpu_pretrained's arms, data, steps and folds with no start: configs/kosmos_e.py:demo_photos
(the from-scratch recipe at its own peak learning rate, 1e-3), the rows beside the pretrained ones.
cornell_grounded: the paper's own Fig. 6 setting, the Cornell photos with more and more augmented views (2, 4,
8 and 16 a photo), each arm the 400-step fine-tune of make demo's 8 x 8 recipe until 2026-12-06
(configs/kosmos_e.py:demo_grounded: steps of 32 at peak rate 3e-4) from the committed grounding start
(pretrained on synthetic scenes only, never a Cornell photo), instruction kind NON, honest protocol, image- and
object-wise folds 0 and 1.
cornell_grounded_epochs: cornell_grounded with the schedule in proportion to the views (100 steps and 25
warm-up steps a view of each photo: 200 steps for 2 views, 1,600 for 16), so every arm makes the same number
of passes over its training views; the 4-view arm is cornell_grounded's own (its fold records serve both:
--records_from=results/data_size_cornell/folds), the others are named by their steps (cornell_aug16_steps1600).
At a fixed 400 steps more views are also fewer passes: this variant separates the two.
paper: Cornell with KOSMOS-E's annotations (configs/kosmos_e.py:paper, KOSMOS-2 initialisation:
--config.init_from), augmentations 4, 8, 16, 32; and synthetic scenes of kind NON, 16
augmentations, 100 to 10,000 photos; both protocols, every fold.

The cpu_demo records in results/ were made before configs/kosmos_e.py:demo gained the tower- and
slot-angle losses (2026-11-26) and before fold records kept their recipe: --records_from cannot
tell them from today's recipe, so a rerun must not carry them in.
"""

from kosmos_jax.experiments.spec import GROUNDING_START, SHIPPED_START, arm, experiment

CPU_STEPS = 200
VARIANTS = ("cpu", "cpu_demo", "cpu_pretrained", "cpu_scratch", "cornell_grounded", "cornell_grounded_epochs", "paper")
PHOTO_COUNTS = (150, 300, 600, 1200)  # cpu_pretrained's and cpu_scratch's arms
CORNELL_AUGMENTATIONS = (2, 4, 8, 16)  # cornell_grounded's arms
STEPS_A_VIEW, WARMUP_A_VIEW = 100, 25  # cornell_grounded_epochs: at 4 views, make demo's own 400 and 100


def get_config(arg: str | None = None):
    variant = arg or "cpu"
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r} of configs/experiments/data_size.py; expected one of {VARIANTS}")
    if variant == "cpu":
        def cpu_arm(photos: int, augmentations: int, series: str):
            return arm("configs/kosmos_e.py:demo_kosmos2", {"data.synthetic_photos": photos, "data.build.kinds": "non",
                                                    "data.build.augmentations": augmentations,
                                                    "train.steps": CPU_STEPS}, series=series)

        arms = {f"photos{p}_aug{a}": cpu_arm(p, a, "augmentations") for p, a in ((300, 2), (300, 8), (300, 16))}
        arms["photos300_aug4"] = cpu_arm(300, 4, "augmentations,photos")
        arms.update({f"photos{p}_aug4": cpu_arm(p, 4, "photos") for p in (100, 1000, 3000)})
        return experiment("data_size", arms, schemes="image,object", protocols="honest", folds="0,1,2",
                          data_size_plot=True)
    if variant == "cpu_demo":
        def demo_arm(photos: int, augmentations: int, series: str):
            return arm("configs/kosmos_e.py:demo", {"data.synthetic_photos": photos, "data.build.kinds": "non",
                                                    "data.build.augmentations": augmentations}, series=series)

        arms = {f"photos{p}_aug16": demo_arm(p, 16, "photos") for p in (100, 1000)}
        arms["photos300_aug16"] = demo_arm(300, 16, "augmentations,photos")
        arms.update({f"photos300_aug{a}": demo_arm(300, a, "augmentations") for a in (4, 8)})
        return experiment("data_size", arms, schemes="image,object", protocols="honest", folds="0", data_size_plot=True)
    if variant == "cpu_pretrained":
        arms = {f"photos{p}_aug4": arm("configs/kosmos_e.py:demo_photos_finetune", {
            "data.synthetic_photos": p, "data.build.kinds": "non", "init_from": SHIPPED_START}, series="photos")
            for p in PHOTO_COUNTS}
        return experiment("data_size", arms, schemes="image", protocols="honest", folds="0,1,2", data_size_plot=True)
    if variant == "cpu_scratch":
        arms = {f"photos{p}_aug4": arm("configs/kosmos_e.py:demo_photos", {
            "data.synthetic_photos": p, "data.build.kinds": "non"}, series="photos") for p in PHOTO_COUNTS}
        return experiment("data_size", arms, schemes="image", protocols="honest", folds="0,1,2", data_size_plot=True)
    if variant in ("cornell_grounded", "cornell_grounded_epochs"):
        def schedule(views: int) -> dict:
            if variant == "cornell_grounded" or views == 4:  # no overrides: the arm and its records are shared
                return {}
            return {"train.steps": STEPS_A_VIEW * views, "optimizer.warmup_steps": WARMUP_A_VIEW * views}

        def name(views: int) -> str:  # an arm of its own schedule has a name of its own
            return f"cornell_aug{views}" + (f"_steps{STEPS_A_VIEW * views}" if schedule(views) else "")

        # NON texts are short: the demo's own 88 tokens rather than the mosaics' 128
        arms = {name(a): arm("configs/kosmos_e.py:demo_grounded", {
            "data.source": "cornell", "data.build.kinds": "non", "data.build.max_length": 88,
            "data.build.augmentations": a, "init_from": GROUNDING_START, **schedule(a)}, series="augmentations")
            for a in CORNELL_AUGMENTATIONS}
        return experiment("data_size", arms, schemes="image,object", protocols="honest", folds="0,1", data_size_plot=True)
    arms = {f"cornell_aug{a}": arm("configs/kosmos_e.py:paper", {"data.build.augmentations": a}, series="augmentations")
            for a in (4, 8, 16, 32)}
    arms.update({f"synthetic{p}": arm("configs/kosmos_e.py:paper", {
        "data.source": "synthetic", "data.synthetic_photos": p, "data.build.kinds": "non", "data.build.annotations": None,
        "data.build.augmentations": 16}, series="photos") for p in (100, 1000, 10_000)})
    return experiment("data_size", arms, schemes="image,object", protocols="honest,paper", data_size_plot=True)
