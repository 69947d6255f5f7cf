"""`python -m kosmos_jax.evaluate --workdir=W`: a trained run's grasps, scored from its decoded answers
(KOSMOS-E) or its predicted grasps (a baseline: GR-ConvNet, GG-CNN2).

Takes a workdir (run.json, checkpoints/; KOSMOS-E's also tokenizer.model) and a split of its data or
a Cornell-format folder; gives WORKDIR/eval/STEP/results.json, results.md and answers.jsonl.
  __main__.py     the command: its flags, what it writes and prints
  run_scores.py   evaluate(workdir, step=..., split=..., cornell=..., kinds=...): a run's results, and
                  write(); what the demo and the experiment runner call
  baseline_run.py a baseline's run, whose views the trainer's code remakes
  overlays.py     `--overlays=N`: scored views drawn with scoring.drawing
The decoding and scoring are kosmos_jax.scoring's; the run is opened through kosmos_jax.workdir.
Scoring a KOSMOS-E run imports nothing of kosmos_jax.train. The diagnostics that read what this
command wrote are kosmos_jax.diagnostics.
"""
