"""The run layer, below training and scoring: what a training run's workdir holds and how to read it.

files.py names the workdir's files (run.json, tokenizer.model) and reads its description;
model.py gives the model a config names; checkpoints.py writes and reads checkpoints/STEP (the
trainer saves the whole train state, readers restore the parameters only); run.py opens a KOSMOS-E
run (its config, tokenizer, model, text format and parameters); export.py writes a run's parameters
as a self-contained KOSMOS-2 folder, with its tokenizer and text format (pretrained.py: kosmos_e.json).
average.py writes the mean of several checkpoints' parameters as such a folder.
The trainer, the evaluation, prediction, the demo and the diagnostics open runs here, so scoring and
prediction import nothing of kosmos_jax.train.
"""
