"""Stage 8, scoring: test views and predicted grasps (of a baseline, or decoded from a model) in, scores out.

Scores under both protocols of DESIGN.md section 3, per fold, beside the baselines that need no
learning (image centre, ground-truth mean); the metric itself is kosmos_jax.metrics. The library
below the `python -m kosmos_jax.evaluate` command (kosmos_jax.evaluate), the trainer and prediction:
  model_scores      a model's grasps on a split, from its decoded answers (GraspEvaluation)
  view_scores       one predicted grasp a view (a trained baseline's), scored as the answers are
  fold_scores       the rectangle metric per fold, mean +- std (the no-learning predictors' tables)
  tally             successes -> accuracy overall, per kind and per scene; its Markdown table
  decoding, prompts, questions, instructions   greedy answers; what is asked; answers -> grasps
  no_learning       the two predictors that learn nothing (the trained baselines are kosmos_jax.baselines)
  cornell_examples  every photo of a Cornell-format folder as examples
  grasp_size        the w, h a predicted (x, y, theta) borrows from the ground truths
  drawing           grasps drawn on images, the paper's Fig. 7 (evaluate --overlays, predict --out)
"""
