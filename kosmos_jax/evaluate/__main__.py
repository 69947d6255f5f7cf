"""Score a trained run's grasps from its greedy answers, with and without the grasp grammar.

    python -m kosmos_jax.evaluate --workdir=runs/demo [--step=N] [--split=test] [--json]
        [--batch_size=16] [--max_examples=0] [--overlays=N] [--nounconstrained] [--mosaic_zoom]
    python -m kosmos_jax.evaluate --workdir=runs/demo --cornell=PATH [--kinds=non] [--json]
    python -m kosmos_jax.evaluate --pretrained=FOLDER --cornell=PATH [--kinds=non] [--out=DIR] [--json]

Writes WORKDIR/eval/STEP/results.json, results.md and answers.jsonl (one line per example: both
answers, whether they parse, its target text, whether its instruction's answers and its targets
make a correct grasp); another split or a Cornell folder goes to eval/STEP/<split> or
eval/STEP/cornell-<folder name>. --json prints results.json as one line on stdout. The split is
scored under the run's protocol; a Cornell folder under the honest one. --pretrained scores a folder
exported from a run (workdir.export) on a Cornell folder alike, into OUT/cornell-<folder name>
(default OUT: runs/evaluate/<the exported folder's name>; never inside the exported folder). results.json holds:
  accuracy           the constrained accuracy overall, in percent;
  constrained, unconstrained   each decoding's accuracy, correct, answers, parse failures
                     (--nounconstrained: the grammar's decoding only, no unconstrained figures);
  target_ceiling     the accuracy of the examples' own targets, read back from their stored tokens
                     and parsed, combined and scored exactly as the answers are: what a model that
                     reproduced its targets would score (below ~100 a flaw of the targets, of
                     combining location and angle, or of the protocol's w and h);
  distinct           {"answers": ..., "targets": ...}: how many distinct texts, centres, angles
                     and combined grasps the constrained answers and the targets hold;
  angle_at_centre    {within_30_deg, instructions, median_deg}: the constrained grasps whose angle is
                     within 30 degrees of the ground truth nearest their centre (the angle judged
                     where the answer put the grasp; an unparsed answer is a miss);
  by_kind, by_scene  {group: accuracy, instructions, examples, unconstrained_accuracy,
                     unconstrained_parse_failures, target_ceiling};
  mosaic_zoom        (--mosaic_zoom) {accuracy, instructions, by_scene, by_kind, mosaics_right_only_zoomed,
                     mosaics_right_only_first}: each mosaic instruction answered again, as NON, on the
                     quadrant its first answer chose, enlarged 2x (scoring/zoom.py); single photos keep
                     their answer. answers.jsonl's mosaic rows add zoom_answer and zoom_correct;
and the run, split, data source, text format and settings it was scored with.

A baseline's run (configs/baselines.py, config.task "baseline") is scored the same way, one
predicted grasp a view as a "non" instruction (baseline_run.py): the same files and keys,
`accuracy` its accuracy in percent, answers.jsonl one line a view with its grasp; its splits are
the fold's test and train views, and --kinds can only be non.

The scoring itself is run_scores.evaluate(workdir, step=..., ...), which the demo and the
experiment runner call directly; this module parses the flags and writes and prints its results.
"""

from __future__ import annotations

import contextlib
import json
import sys

from absl import flags

from kosmos_jax import commands
from kosmos_jax.evaluate.overlays import write_overlays
from kosmos_jax.evaluate.pretrained_scores import evaluate_pretrained
from kosmos_jax.evaluate.run_scores import evaluate, write
from kosmos_jax.models.value_decoding import MAX_ANGLE_WINDOW
from kosmos_jax.scoring.tally import markdown
from kosmos_jax.workdir.files import RunError


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("string", "workdir", None, "the training run's folder")
    define("string", "pretrained", None, "a folder exported from a run (workdir.export) instead; needs --cornell")
    define("string", "out", None, "with --pretrained: where the scores go (default runs/evaluate/<its name>)")
    define("integer", "step", None, "checkpoint step (default: the newest)")
    define("string", "split", "test", "split of the run's dataset")
    define("string", "cornell", None, "score every photo of this Cornell-format folder instead")
    define("list", "kinds", ["non"], "instruction kinds for --cornell, comma-separated, as the build names them")
    define("integer", "batch_size", 16, "examples decoded at once", lower_bound=1)
    define("integer", "max_examples", 0, "decode at most this many examples (0: all)", lower_bound=0)
    define("integer", "value_window", None, "N: read coordinate value tokens as the local mean within N values of "
           "the mode (0: greedy; default: the run's config.decode.value_window, 0 for runs made before it)",
           lower_bound=0)
    define("integer", "angle_window", None, "N: read angle tokens as the circular local mean within N bins of the "
           "mode (0: the mode; default: the run's config.decode.angle_window, 0 for runs made before it)",
           lower_bound=0, upper_bound=MAX_ANGLE_WINDOW)
    define("bool", "unconstrained", True, "also decode without the grammar (the unconstrained_* figures); "
           "--nounconstrained decodes with the grammar only, in about half the time")
    define("bool", "mosaic_zoom", False, "also answer each mosaic instruction again on the quadrant its first "
           "answer chose, enlarged 2x (scoring/zoom.py): results' mosaic_zoom figures beside the one-pass ones")
    define("bool", "json", False, "print results.json as one line on stdout")
    define("integer", "overlays", 0, "N: draw N scored views of each instruction kind to "
           "eval/STEP/overlays/KIND.png (overlays.py)", lower_bound=0)
    flags.register_multi_flags_validator(
        ["workdir", "pretrained"], lambda given: (given["workdir"] is None) != (given["pretrained"] is None),
        message="give --workdir=RUN or --pretrained=FOLDER (one of them)", flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_flags, evaluate_command, argv, prog="python -m kosmos_jax.evaluate", doc=__doc__)


def pretrained_misuse(args) -> str | None:
    """What --pretrained cannot be given with, in one line; None when nothing."""
    if args.cornell is None:
        return "--pretrained scores a Cornell-format folder: give --cornell=PATH (an exported folder has no dataset)"
    given = [name for name, value, unset in (("step", args.step, None), ("split", args.split, "test"),
                                              ("overlays", args.overlays, 0)) if value != unset]
    if given:
        return f"--{given[0]} belongs to --workdir runs; an exported folder holds one step and no splits"
    return None


def evaluate_command(args) -> int:
    if args.pretrained is None and args.out is not None:
        print("error: --out goes with --pretrained; a run's scores go to WORKDIR/eval/STEP", file=sys.stderr)
        return 1
    if args.pretrained is not None and (misuse := pretrained_misuse(args)):
        print(f"error: {misuse}", file=sys.stderr)
        return 1
    asked = dict(kinds=tuple(args.kinds), batch_size=args.batch_size, max_examples=args.max_examples,
                 value_window=args.value_window, angle_window=args.angle_window, unconstrained=args.unconstrained,
                 mosaic_zoom=args.mosaic_zoom)
    try:
        with contextlib.redirect_stdout(sys.stderr):  # stdout holds the results only
            if args.pretrained is not None:
                results, rows, folder = evaluate_pretrained(args.pretrained, cornell=args.cornell, out=args.out,
                                                            **asked)
            else:
                results, rows, folder = evaluate(args.workdir, step=args.step, split=args.split,
                                                 cornell=args.cornell, **asked)
            write(results, rows, folder)
            if args.workdir is not None:
                write_overlays(args.workdir, results, rows, folder, args.overlays)
    except (RunError, FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    if args.json:
        print(json.dumps(results))
    else:
        print(markdown(results) + f"\nwritten to {folder}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
