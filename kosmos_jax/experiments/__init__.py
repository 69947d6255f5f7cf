"""`python -m kosmos_jax.experiments`: the paper's experiments as k-fold cross-validated sweeps.

An experiment config (configs/experiments/*.py, helpers in spec.py) names arms (a training config
file, its variant and dotted overrides), schemes (image- and/or object-wise folds), protocols
(honest and/or paper) and folds. For each (arm, protocol, scheme, fold) the runner (runner.py)
trains the arm's config in WORKDIR/<arm>/<protocol>-<scheme>-fold<i> with the project's trainer,
scores it with the evaluate command's code, scores the two no-learning predictors on the same test
examples (no_learning.py), and writes the fold's record (fold.json); a fold with a record is
skipped, so a killed sweep resumes. aggregate.py turns the records into WORKDIR/results.json and
table.md; data_size.py into the Fig. 6 plot and its data; checks.py builds every arm's model (by
jax.eval_shape) and checks its data settings without training.
"""
