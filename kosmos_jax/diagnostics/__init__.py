"""Diagnostics: why a trained run scores what it scores. Not stages of the pipeline: each takes a
workdir (most after `python -m kosmos_jax.evaluate` has scored it) and gives figures to read, on
stdout (--json: one line) and, for image_use, in WORKDIR/eval/STEP/image_use.json.

    python -m kosmos_jax.diagnostics.answer_errors --workdir=W [--step=N] [--scored=FOLDER] [--json]
        how far the decoded answers fall from their targets: centre in pixels, angle in degrees
    python -m kosmos_jax.diagnostics.part_oracles --workdir=W [--step=N] [--json]
        the answers scored again with the angle, or the centre, taken from the ground truth
    python -m kosmos_jax.diagnostics.image_use --workdir=W [--step=N] [--split=test] [--batches=4] [--json]
        does the model read its image: the answers' loss with its own, another photo's, a blank image
    python -m kosmos_jax.diagnostics.vision_probe --workdir=W [--steps=300] [--readout=patches] [--json]
        can a fresh vision tower of the run's config find the grasp centre at all (a trained probe)
    python -m kosmos_jax.diagnostics.angle_probe --workdir=W [--step=N] [--examples=3000] [--json]
        where the model loses the grasp's angle: ridge readouts at the tower, the slots, the decoder
    python -m kosmos_jax.diagnostics.object_probe --workdir=W [--step=N] [--examples=2000] [--json]
        where a mosaic's named object is lost: does the tower see each photo's object, do the slots
        and the decoder know which quadrant the words name
    python -m kosmos_jax.diagnostics.categories --workdir=W --scored=cornell-NAME [--json]
        a scored synthetic folder's single-photo answers by object category, the part oracles beside them
    python -m kosmos_jax.diagnostics.annotation_draws --workdir=W --scored=cornell-NAME [--draws=100] [--json]
        the answers against fresh draws of each synthetic photo's grasps, beside the best answer found
"""
