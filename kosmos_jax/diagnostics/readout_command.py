"""The command line the readout probes (angle_probe, object_probe) share: a run's workdir, a checkpoint
step, how many training examples the readouts are fit on, the ridge penalty, --json."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable

from absl import flags

from kosmos_jax import commands
from kosmos_jax.workdir.files import RunError


def readout_command(argv, *, prog: str, doc: str, probe: Callable[..., dict], report: Callable[[dict], None],
                    examples: int, examples_help: str, least: int) -> int:
    """Parse `argv`, run `probe(workdir, step, examples, ridge)` and print its result: one JSON line with
    --json, else `report(result)`; a run that cannot be probed is one line on stderr and status 1."""

    def define_flags(flag_values: flags.FlagValues) -> None:
        define = commands.definer(flag_values)
        define("string", "workdir", None, "a KOSMOS-E training run's folder")
        define("integer", "step", None, "checkpoint step (default: the newest)")
        define("integer", "examples", examples, examples_help, lower_bound=least)
        define("float", "ridge", 0.01, "ridge penalty per example, on standardised features")
        define("bool", "json", False, "print the result as one JSON line")
        flags.mark_flag_as_required("workdir", flag_values=flag_values)

    def body(args) -> int:
        try:
            result = probe(args.workdir, args.step, args.examples, args.ridge)
        except RunError as error:
            print(f"error: {error}", file=sys.stderr)
            return 1
        if args.json:
            print(json.dumps(result))
        else:
            report(result)
        return 0

    return commands.run_command(define_flags, body, argv, prog=prog, doc=doc)
