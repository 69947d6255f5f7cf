"""What each half of a run's answers costs it: its grasps scored again with one half from the truth.

    python -m kosmos_jax.diagnostics.part_oracles --workdir=runs/demo [--step=N] [--scored=NAME] [--json]

Reads WORKDIR/eval/STEP/answers.jsonl (run `python -m kosmos_jax.evaluate --workdir=...` first) and
the test split's instructions, or with --scored (e.g. cornell-synthetic-60-seed7) the answers that
`evaluate --cornell` wrote under eval/STEP/NAME and that folder's instructions, remade as evaluate
made them (its results.json names the folder and the kinds), and scores three grasps an instruction
with the run's protocol (the honest one for a scored folder):
  model        the answered centre and angle: the evaluate command's accuracy;
  true_angle   the answered centre with the angle of the ground truth nearest to it: what the model
               would score if its angles were right;
  true_centre  the answered angle at the centre of that same ground truth: what it would score if
               its centres were right.
An instruction that states its angle keeps that angle in all three. An answer that does not parse
is a miss in all three: no ground truth ever stands in for a missing answer.
"""

from __future__ import annotations

import json
import pathlib
import sys
from collections.abc import Mapping, Sequence

import numpy as np

from kosmos_jax import commands
from kosmos_jax.diagnostics.answer_errors import define_scored_run_flags, read_answers
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.instructions import Instruction, combine, group_instructions
from kosmos_jax.text.formatter import FormatConfig, parse_target
from kosmos_jax.workdir.checkpoints import chosen_step
from kosmos_jax.workdir.files import RunError
from kosmos_jax.workdir.run import open_run

SCORES = ("model", "true_angle", "true_centre")


def nearest_truths(instructions: Sequence[Instruction], grasps: np.ndarray) -> np.ndarray:
    """[G, 5] the ground truth of each instruction whose centre is nearest the answered centre
    (NaN where the answer did not parse)."""
    truths = np.full((len(instructions), 5), np.nan)
    for row, (instruction, grasp) in enumerate(zip(instructions, grasps)):
        if np.isfinite(grasp).all():
            distances = np.hypot(*(instruction.answers[:, :2] - grasp[:2]).T)
            truths[row] = instruction.answers[np.argmin(distances)]
    return truths


def oracle_grasps(instructions: Sequence[Instruction], grasps: np.ndarray) -> dict[str, np.ndarray]:
    """{score name: [G, 3] (x, y, theta)}: the model's grasps and the two with half from the truth."""
    truths = nearest_truths(instructions, grasps)
    answers_angle = np.array([instruction.answer != "centre" for instruction in instructions])
    true_angle, true_centre = grasps.copy(), grasps.copy()
    true_angle[answers_angle, 2] = truths[answers_angle, 4]
    true_centre[:, :2] = truths[:, :2]
    return {"model": grasps, "true_angle": true_angle, "true_centre": true_centre}


def answered_grasps(instructions: Sequence[Instruction], rows: Sequence[Mapping], config: FormatConfig) -> np.ndarray:
    """[G, 3] each instruction's grasp from its examples' answers, as the evaluation combines them."""
    parsed = {row["example"]: parse_target(row["answer"], row["part"], config) for row in rows}
    missing = sorted({i for instruction in instructions for i in instruction.examples.values()} - set(parsed))
    if missing:
        raise RunError(f"answers.jsonl has no answer for {len(missing)} test examples (first {missing[0]}): it was "
                       "decoded with --max_examples; evaluate the whole split first")
    return np.stack([combine(instruction, {part: parsed[index] for part, index in instruction.examples.items()})
                     for instruction in instructions])


def part_oracles(records: Sequence[Mapping], rows: Sequence[Mapping], config: FormatConfig, protocol: str) -> dict:
    """{"instructions": n, "accuracy": {score: percent}, "by_kind": {kind: {score: percent}}}."""
    instructions = group_instructions(records)
    grasps = answered_grasps(instructions, rows, config)
    hits = {name: tally.successes(instructions, made, protocol) for name, made in oracle_grasps(instructions, grasps).items()}
    kinds = tally.group_members(instructions, lambda instruction: instruction.kind)
    return {"instructions": len(instructions), "accuracy": {name: tally.percent(hits[name]) for name in SCORES},
            "by_kind": {kind: {name: tally.percent(hits[name][idx]) for name in SCORES} for kind, idx in kinds.items()}}


def scored_records(run, step: int, scored: str) -> tuple[Sequence[Mapping], str, str | None]:
    """(records, protocol, Cornell-format folder) of the answers read: the run's test split (folder None),
    or the folder evaluate --cornell scored."""
    if not scored:
        return run.split("test").examples, run.protocol, None
    results_path = run.workdir / "eval" / str(step) / scored / "results.json"
    if not results_path.is_file():
        raise RunError(f"no {results_path}: score the folder first with python -m kosmos_jax.evaluate "
                       f"--workdir={run.workdir} --step={step} --cornell=...")
    results = json.loads(results_path.read_text())
    if "cornell" not in results:
        raise RunError(f"{results_path} is not a scored Cornell-format folder (no 'cornell' key)")
    made = cornell_examples(results["cornell"], run.tokenizer, run.format_config, results["kinds"])
    return made.records, "honest", results["cornell"]


def scored_folder_answers(args, why: str):
    """(run, step, records, protocol, folder, answers) of the answers `evaluate --cornell` wrote for the folder
    that --scored names (args: --workdir, --step, --scored); a command that needs such a folder says `why`."""
    if not args.scored:
        raise RunError(f"give --scored=cornell-NAME: {why}")
    workdir = pathlib.Path(args.workdir)
    run = open_run(workdir)
    step = chosen_step(workdir, args.step)
    records, protocol, folder = scored_records(run, step, args.scored)
    return run, step, records, protocol, folder, read_answers(workdir, step, args.scored)


def main(argv=None) -> int:
    return commands.run_command(define_scored_run_flags, oracles_command, argv,
                                prog="python -m kosmos_jax.diagnostics.part_oracles", doc=__doc__)


def oracles_command(args) -> None:
    workdir = pathlib.Path(args.workdir)
    try:
        run = open_run(workdir)
        step = chosen_step(workdir, args.step)
        records, protocol, _ = scored_records(run, step, args.scored)
        figures = {"step": step, "protocol": protocol, "scored": args.scored or "test",
                   **part_oracles(records, read_answers(workdir, step, args.scored), run.format_config, protocol)}
    except RunError as error:
        raise SystemExit(f"error: {error}") from None
    if args.json:
        print(json.dumps(figures))
        return
    print(f"step {step}, {figures['instructions']} instructions of {figures['scored']}, {protocol} protocol: accuracy in percent")
    print(f"{'kind':<16}" + "".join(f"{name:>13}" for name in SCORES))
    for kind, scores in [("all", figures["accuracy"]), *sorted(figures["by_kind"].items())]:
        print(f"{kind:<16}" + "".join(f"{scores[name]:>13.2f}" for name in SCORES))
    print("true_angle: the answered centre with the nearest ground truth's angle; "
          "true_centre: the answered angle at that ground truth's centre")


if __name__ == "__main__":
    sys.exit(main())
