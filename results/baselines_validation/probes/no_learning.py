"""The no-learning rows (image centre, ground-truth-mean oracle) on a baseline run's own test views:
what its test accuracy sits between. Run from the repository root:

    python results/baselines_validation/probes/no_learning.py RUN_WORKDIR [RUN_WORKDIR ...]
"""

import sys

from kosmos_jax.evaluate.baseline_run import open_baseline_run
from kosmos_jax.experiments.no_learning import predict
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.no_learning import PREDICTORS
from kosmos_jax.scoring.view_scores import view_instructions

for workdir in sys.argv[1:]:
    run = open_baseline_run(workdir)
    views = run.split("test")
    instructions = view_instructions(views)
    for name in PREDICTORS:
        hits = tally.successes(instructions, predict(name, instructions, views.images.shape[1]), run.protocol)
        print(f"{workdir}: fold {run.config.data.fold} ({run.config.data.scheme}-wise, {run.protocol}), {name}: "
              f"{tally.percent(hits):.2f}% ({int(hits.sum())} of {len(instructions)} test views)")
