"""Stage 8, evaluation: test views and predicted grasps (of a baseline, or decoded from a model) in, scores out.

Scores under both protocols of DESIGN.md section 3, per fold, beside the baselines that need no
learning (image centre, ground-truth mean); the metric itself is kosmos_jax.metrics.
"""
