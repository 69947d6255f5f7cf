"""How far a run's decoded answers fall from their targets: centre distance and angle error.

    python -m kosmos_jax.diagnostics.answer_errors --workdir=runs/demo [--step=N] [--scored=FOLDER] [--json]

Reads WORKDIR/eval/STEP/answers.jsonl (run `python -m kosmos_jax.evaluate --workdir=...` first).
Each answer is compared with its example's own target grasp (one ground truth of the view, the one
the example was formatted from), not with the nearest ground truth as the rectangle metric does:
these figures say where the misses come from, the metric says what counts. Centre distances are in
pixels of the view (the grasp text's image), angle errors in degrees modulo 180. An answer that does
not parse counts as a miss at every threshold and is left out of the median.

Split by scene (single photos, four-photo mosaics), and for mosaics the share of centre answers that
fall in the target's quadrant (`same_quadrant`): whether the model picked the named photo at all
(a quarter by chance), apart from how close it came within it (of those answers, the share the
rectangle metric scored right).
"""

from __future__ import annotations

import json
import math
import pathlib
import sys

import numpy as np
from absl import flags

from kosmos_jax import commands, geometry
from kosmos_jax.workdir.checkpoints import chosen_step
from kosmos_jax.workdir.files import RunError, read_description
from kosmos_jax.text.formatter import FormatConfig, parse_target

CENTRE_PX = (10, 20)
ANGLE_DEG = (15, 30)


def answer_errors(row: dict, config: FormatConfig) -> tuple[float, float]:
    """(centre distance px, angle error deg) of one answers.jsonl row; NaN where the part does not
    state it, inf where the answer does not parse."""
    target = parse_target(row["target_text"], row["part"], config).grasp
    parsed = parse_target(row["answer"], row["part"], config)
    answer = parsed.grasp if parsed.ok else np.full(5, np.inf)
    centre = math.hypot(*(answer[:2] - target[:2])) if not np.isnan(target[:2]).any() else math.nan
    if np.isnan(target[4]):
        return centre, math.nan
    return centre, math.degrees(geometry.angle_difference(answer[4], target[4])) if parsed.ok else math.inf


def summarise(errors: np.ndarray, thresholds: tuple[int, ...], unit: str) -> dict | None:
    errors = errors[~np.isnan(errors)]
    if not len(errors):
        return None
    parsed = errors[np.isfinite(errors)]
    return {"answers": int(len(errors)), "unparsed": int(len(errors) - len(parsed)),
            "median": round(float(np.median(parsed)), 2) if len(parsed) else None,
            **{f"within_{t}_{unit}": round(float((errors <= t).mean()), 4) for t in thresholds}}


def quadrant(centre, side: float) -> int:
    """The 2 x 2 mosaic tile (instruct.mosaic's quadrant order: row-major) a view's point lies in."""
    return 2 * int(centre[1] >= side / 2) + int(centre[0] >= side / 2)


def same_quadrant(rows: list[dict], config: FormatConfig) -> dict | None:
    """Of the mosaic rows that state a centre: how many answers parse to one in the target's quadrant
    (`share`), and of those how many the rectangle metric scored right (`correct_share`: the grasp within
    the named photo, apart from finding it)."""
    hits, right, stated = 0, 0, 0
    for row in rows:
        target = parse_target(row["target_text"], row["part"], config).grasp
        if np.isnan(target[:2]).any():
            continue
        stated += 1
        parsed = parse_target(row["answer"], row["part"], config)
        hit = bool(parsed.ok) and quadrant(parsed.grasp, config.image_size) == quadrant(target, config.image_size)
        hits += hit
        right += hit and bool(row.get("correct"))
    if not stated:
        return None
    return {"answers": stated, "share": round(hits / stated, 4),
            "correct_share": round(right / hits, 4) if hits else None}


def error_summary(rows: list[dict], config: FormatConfig) -> dict:
    """{"centre_px": {...}, "angle_deg": {...}, "examples": n, "distinct_answers": n, "by_scene": {...}}: per
    part, the median and the share within each threshold (None for a part no row states); by_scene holds
    the same per scene, mosaics with `same_quadrant`."""
    summary = part_summary(rows, config)
    scenes = sorted({row.get("scene", "single") for row in rows})
    summary["by_scene"] = {scene: part_summary([r for r in rows if r.get("scene", "single") == scene], config)
                           for scene in scenes}
    if "multi" in summary["by_scene"]:
        mosaic_rows = [r for r in rows if r.get("scene") == "multi"]
        summary["by_scene"]["multi"]["same_quadrant"] = same_quadrant(mosaic_rows, config)
        # the position kind names the quadrant in words; the others name the object: telling them apart
        # says whether a model reads the instruction or the photo's content
        kinds = sorted({r.get("kind", "") for r in mosaic_rows})
        summary["by_scene"]["multi"]["same_quadrant_by_kind"] = {
            kind: same_quadrant([r for r in mosaic_rows if r.get("kind", "") == kind], config) for kind in kinds}
    return summary


def part_summary(rows: list[dict], config: FormatConfig) -> dict:
    errors = np.array([answer_errors(row, config) for row in rows], np.float64).reshape(-1, 2)
    return {"centre_px": summarise(errors[:, 0], CENTRE_PX, "px"), "angle_deg": summarise(errors[:, 1], ANGLE_DEG, "deg"),
            "examples": len(rows), "distinct_answers": len({row["answer"] for row in rows})}


def read_answers(workdir: pathlib.Path, step: int, scored: str = "") -> list[dict]:
    """The answers of `evaluate` at `step`: of the run's own test split, or of the folder `scored` names
    under eval/STEP (e.g. cornell-synthetic-60-seed7, written by evaluate --cornell)."""
    path = workdir / "eval" / str(step) / scored / "answers.jsonl"
    if not path.is_file():
        source = " --cornell=..." if scored else ""
        raise RunError(f"no {path}: score the run first with python -m kosmos_jax.evaluate --workdir={workdir} "
                       f"--step={step}{source}")
    return answer_rows(path)


def answer_rows(path: pathlib.Path) -> list[dict]:
    """The rows of an answers.jsonl that evaluate wrote."""
    return [json.loads(line) for line in path.read_text().splitlines() if line]


def define_scored_run_flags(flag_values: flags.FlagValues) -> None:
    """--workdir, --step, --scored and --json of a command that reads a scored run's answers."""
    define = commands.definer(flag_values)
    define("string", "workdir", None, "the training run's folder")
    define("integer", "step", None, "checkpoint step (default: the newest)")
    define("string", "scored", "", "the answers of eval/STEP/SCORED (what evaluate --cornell wrote, e.g. "
           "cornell-synthetic-60-seed7) instead of the run's test split")
    define("bool", "json", False, "print the figures as one JSON line")
    flags.mark_flag_as_required("workdir", flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_scored_run_flags, errors_command, argv,
                                prog="python -m kosmos_jax.diagnostics.answer_errors", doc=__doc__)


def errors_command(args) -> None:
    workdir = pathlib.Path(args.workdir)
    try:
        config = FormatConfig(**read_description(workdir)["data_identity"]["format"])
        step = chosen_step(workdir, args.step)
        summary = {"step": step, **error_summary(read_answers(workdir, step, args.scored), config)}
    except RunError as error:
        raise SystemExit(f"error: {error}") from None
    if args.json:
        print(json.dumps(summary))
        return
    print(f"step {step}: {summary['examples']} answers, {summary['distinct_answers']} distinct; against each example's target grasp")
    for part, figures in (("centre", summary["centre_px"]), ("angle", summary["angle_deg"])):
        if figures:
            within = ", ".join(f"{v:.0%} {k.removeprefix('within_').replace('_', ' ')}" for k, v in figures.items()
                               if k.startswith("within_"))
            print(f"  {part}: {figures['answers']} answers ({figures['unparsed']} unparsed), median {figures['median']}, within: {within}")
    mosaics = summary["by_scene"].get("multi", {}).get("same_quadrant")
    if mosaics:
        right = "" if mosaics["correct_share"] is None else f", {mosaics['correct_share']:.0%} of those right"
        print(f"  mosaics: {mosaics['share']:.0%} of {mosaics['answers']} centres in the target's quadrant (chance 25%){right}")


if __name__ == "__main__":
    sys.exit(main())
