"""Stage 9, evaluation: test views and predicted grasps in, rectangle-metric scores out.

Scores under both protocols of DESIGN.md section 3, per fold, beside the baselines that need no
learning (image centre, ground-truth mean); the metric itself is kosmos_jax.metrics.
"""
