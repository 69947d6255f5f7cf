"""`python -m kosmos_jax.train --config=configs/kosmos_e.py:tiny --workdir=runs/tiny [--config.train.steps=N]`

Trains the config's model on its dataset (built on first use); run again on the same workdir, it
resumes from the newest checkpoint, and a finished run says so and exits 0.
"""

import sys

from absl import app, flags, logging
from ml_collections import config_flags

config_flags.DEFINE_config_file("config", None, "an ml-collections config file, e.g. configs/kosmos_e.py:tiny",
                                lock_config=True)
flags.DEFINE_string("workdir", None, "the run's folder: checkpoints, metrics.jsonl, TensorBoard files")
flags.mark_flags_as_required(["config", "workdir"])


def main(argv):
    if len(argv) > 1:
        raise app.UsageError(f"unexpected arguments: {argv[1:]}")
    logging.set_verbosity(logging.WARNING)  # orbax and tfds log every file they touch at INFO
    from kosmos_jax.train.trainer import NonFiniteError, RunMismatchError, train

    try:
        summary = train(flags.FLAGS.config, flags.FLAGS.workdir)
    except (NonFiniteError, RunMismatchError, FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    if summary.get("stopped") == "preempted":
        print(f"stopped by SIGTERM at step {summary['step']}; checkpoint saved", file=sys.stderr)
    return 0


if __name__ == "__main__":
    app.run(main)
