"""`python -m kosmos_jax.train --config=configs/kosmos_e.py:tiny --workdir=runs/tiny [--config.train.steps=N]`

Trains the config's model on its dataset (built on first use); run again on the same workdir, it
resumes from the newest checkpoint, and a finished run says so and exits 0.
"""

import sys

from absl import flags, logging

from kosmos_jax import commands


def define_flags(flag_values: flags.FlagValues) -> None:
    commands.define_config(flag_values, "config", None, "an ml-collections config file, e.g. configs/kosmos_e.py:tiny")
    flags.DEFINE_string("workdir", None, "the run's folder: checkpoints, metrics.jsonl, TensorBoard files",
                        flag_values=flag_values)
    flags.mark_flags_as_required(["config", "workdir"], flag_values=flag_values)


def train_command(options) -> int:
    logging.set_verbosity(logging.WARNING)  # orbax and tfds log every file they touch at INFO
    from kosmos_jax.train.trainer import NonFiniteError, RunMismatchError, train

    try:
        summary = train(options.config, options.workdir)
    except (NonFiniteError, RunMismatchError, FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    if summary.get("stopped") == "preempted":
        print(f"stopped by SIGTERM at step {summary['step']}; checkpoint saved", file=sys.stderr)
    return 0


def main(argv=None) -> int:
    return commands.run_command(define_flags, train_command, argv, prog="python -m kosmos_jax.train", doc=__doc__)


if __name__ == "__main__":
    sys.exit(main())
