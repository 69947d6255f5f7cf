"""`python -m kosmos_jax.evaluate --workdir=W`: a trained run's grasps, scored from its decoded answers.

Takes a workdir (run.json, tokenizer.model, checkpoints/) and a split of its dataset or a
Cornell-format folder; gives WORKDIR/eval/STEP/results.json, results.md and answers.jsonl. The
decoding and scoring are kosmos_jax.evaluation's; this stage reads back what the trainer wrote.
"""
