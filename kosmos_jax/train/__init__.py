"""The training stage: takes batches of the dataset stage and a model of models/, gives updated
parameters, optimiser state and metrics (one jitted, sharded step; AdamW with warm-up and decay)."""
