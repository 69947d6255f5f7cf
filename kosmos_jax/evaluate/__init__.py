"""`python -m kosmos_jax.evaluate --workdir=W`: a trained run's grasps, scored from its decoded answers
(KOSMOS-E) or its predicted grasps (a baseline: GR-ConvNet, GG-CNN2).

Takes a workdir (run.json, checkpoints/; KOSMOS-E's also tokenizer.model) and a split of its data or
a Cornell-format folder; gives WORKDIR/eval/STEP/results.json, results.md and answers.jsonl
(overlays.py draws `--overlays=N` of the scored views with scoring.drawing). The decoding and
scoring are kosmos_jax.scoring's; the run is opened through kosmos_jax.workdir
(KOSMOS-E's runs and what every run holds; baseline_run.py: a baseline's, whose views the trainer's
code remakes). Scoring a KOSMOS-E run imports nothing of kosmos_jax.train.
"""
