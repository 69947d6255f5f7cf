"""Stage 9, training: batches of the dataset stage and a model of models/ in; updated parameters,
optimiser state, checkpoints and metrics out (one jitted, sharded step; AdamW with warm-up and decay;
the trainer, its launchers' set-up, and the TPU memory plan by compilation)."""
