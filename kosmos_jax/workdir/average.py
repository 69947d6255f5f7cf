"""The mean of several checkpoints' parameters, written as an exported folder (workdir.export's layout).

    python -m kosmos_jax.workdir.average --workdirs=runs/ft_s0 --steps=250,300,350,400 --out=exported/tail
    python -m kosmos_jax.workdir.average --workdirs=runs/ft_s0,runs/ft_s1,runs/ft_s2 --out=exported/soup

Every pair of a workdir and a step is one checkpoint (--steps default: each run's newest), and each counts
once: the tail of one run's checkpoints, or the last checkpoints of fine-tunes from one start (a "model
soup"). The runs must share their model, tokenizer and text format, so that one parameter means the same
in each. The folder is read like any export: `evaluate --pretrained=OUT`, `predict --pretrained=OUT`,
`train --config.init_from=OUT`; its kosmos_e.json describes the first run at its last step and lists the
averaged checkpoints in `averaged_from`.
"""

from __future__ import annotations

import sys

import jax
import jax.numpy as jnp
from absl import flags

from kosmos_jax import commands
from kosmos_jax.workdir.export import check_new_folder, one_device_mesh, write_exported
from kosmos_jax.workdir.files import TOKENIZER_FILE
from kosmos_jax.workdir.run import open_run


def add_float32(total, params):
    """`total` + `params`, leafwise in float32 (`total` None: `params` in float32)."""
    if total is None:
        return jax.tree.map(lambda leaf: leaf.astype(jnp.float32), params)
    return jax.tree.map(lambda kept, leaf: kept + leaf.astype(jnp.float32), total, params)


def same_model_runs(workdirs: list[str]) -> list:
    """The opened runs, checked to share the first one's model, tokenizer and text format."""
    runs = [open_run(workdir) for workdir in workdirs]
    first = runs[0]
    tokenizer_bytes = (first.workdir / TOKENIZER_FILE).read_bytes()
    for run in runs[1:]:
        for what, mine, theirs in (("model", run.model_config, first.model_config),
                                   ("text format", run.format_config, first.format_config)):
            if mine != theirs:
                raise ValueError(f"{run.workdir} has another {what} than {first.workdir}; only checkpoints of one "
                                 "model can be averaged")
        if (run.workdir / TOKENIZER_FILE).read_bytes() != tokenizer_bytes:
            raise ValueError(f"{run.workdir} has another {TOKENIZER_FILE} than {first.workdir}: its token ids mean "
                             "other pieces")
    return runs


def average_checkpoints(workdirs: list[str], steps: list[int] | None, folder) -> list[dict]:
    """Write the mean of each workdir's checkpoints `steps` (None: its newest) to the new folder `folder`;
    returns the averaged checkpoints as [{"workdir", "step"}]."""
    if len(set(workdirs)) != len(workdirs):
        raise ValueError(f"a workdir is named twice in {workdirs}")
    if steps is not None and len(set(steps)) != len(steps):
        raise ValueError(f"a step is named twice in {steps}")
    if len(workdirs) * (len(steps) if steps else 1) < 2:
        raise ValueError("name at least two checkpoints (two workdirs or two steps); one checkpoint alone is "
                         "written by python -m kosmos_jax.workdir.export")
    check_new_folder(folder)
    runs = same_model_runs(workdirs)
    mesh = one_device_mesh()
    total, averaged = None, []
    for run in runs:  # one checkpoint in memory at a time, beside the float32 sum
        for wanted in steps or [None]:
            step, params = run.params(wanted, mesh)
            dtypes = jax.tree.map(lambda leaf: leaf.dtype, params)
            total = add_float32(total, params)
            averaged.append({"workdir": str(run.workdir.resolve()), "step": int(step)})
            print(f"read step {step} of {run.workdir}", flush=True)
    mean = jax.tree.map(lambda kept, dtype: (kept / len(averaged)).astype(dtype), total, dtypes)
    newest_of_first = max(entry["step"] for entry in averaged if entry["workdir"] == averaged[0]["workdir"])
    write_exported(runs[0], newest_of_first, mean, folder, averaged_from=averaged)
    return averaged


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("list", "workdirs", None, "KOSMOS-E training runs, comma-separated")
    define("list", "steps", None, "the checkpoints of each run to average, comma-separated (default: its newest)")
    define("string", "out", None, "the folder to write (new or empty)")
    flags.mark_flags_as_required(["workdirs", "out"], flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_flags, average_command, argv, prog="python -m kosmos_jax.workdir.average",
                                doc=__doc__)


def step_number(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ValueError(f"--steps: {text!r} is not a step number") from None


def average_command(args) -> int:
    try:
        steps = [step_number(step) for step in args.steps] if args.steps else None
        averaged = average_checkpoints(list(args.workdirs), steps, args.out)
    except (OSError, ValueError) as error:  # workdir.files.RunError is a FileNotFoundError
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(f"the mean of {len(averaged)} checkpoints written to {args.out}; "
          f"score with: python -m kosmos_jax.evaluate --pretrained={args.out} --cornell=PHOTOS")
    return 0


if __name__ == "__main__":
    sys.exit(main())
