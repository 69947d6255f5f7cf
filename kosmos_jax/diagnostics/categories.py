"""A run's answers on a scored synthetic folder, object category by object category.

    python -m kosmos_jax.diagnostics.categories --workdir=runs/demo --scored=cornell-synthetic-300-seed7 [--step=N] [--json]

Reads what `python -m kosmos_jax.evaluate --workdir=... --cornell=FOLDER` wrote under eval/STEP/SCORED
and FOLDER's synthetic_meta.json (the category of each photo: only folders that
`kosmos_jax.sources.synthetic` wrote have one), and splits the single-photo instructions by their
photo's category: for each, the instructions, the accuracy with the part oracles of `part_oracles`
beside it (true_angle, true_centre), and the median distance in pixels from each answered centre to
the nearest ground-truth centre. A category the model answers badly with its centres right where its
angle is, or the other way, shows here where the overall figures average it away. Mosaics name one
object of four and are left out.
"""

from __future__ import annotations

import json
import pathlib
import sys
from collections.abc import Mapping, Sequence

import numpy as np

from kosmos_jax import commands
from kosmos_jax.diagnostics.answer_errors import define_scored_run_flags
from kosmos_jax.diagnostics.part_oracles import SCORES, answered_grasps, nearest_truths, oracle_grasps, scored_folder_answers
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.instructions import group_instructions, text
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.workdir.files import RunError

META = scenes.META_NAME


def synthetic_header(folder: str | pathlib.Path, why: str) -> dict:
    """scenes.read_header of a folder the synthetic generator wrote, its refusals as RunError ending in `why`."""
    try:
        return scenes.read_header(folder)
    except (FileNotFoundError, ValueError) as error:
        raise RunError(f"{error}: {why}") from None


def photo_categories(folder: str | pathlib.Path) -> dict[str, str]:
    """{photo id: category} of a synthetic folder, from its synthetic_meta.json."""
    header = synthetic_header(folder, "categories are known only for folders written by python -m kosmos_jax.sources.synthetic")
    return {photo: about["category"] for photo, about in header["photos"].items()}


def by_category(records: Sequence[Mapping], rows: Sequence[Mapping], config: FormatConfig, protocol: str,
                categories: Mapping[str, str]) -> dict[str, dict]:
    """{category: {"instructions", SCORES..., "median_centre_px"}} of the single-photo instructions."""
    instructions = [i for i in group_instructions(records) if i.scene == "single"]
    grasps = answered_grasps(instructions, rows, config)
    hits = {name: np.asarray(tally.successes(instructions, made, protocol))
            for name, made in oracle_grasps(instructions, grasps).items()}
    distance = np.hypot(*(nearest_truths(instructions, grasps)[:, :2] - grasps[:, :2]).T)
    photo = lambda instruction: text(records[min(instruction.examples.values())]["photo_ids"][0])
    missing = sorted({photo(instruction) for instruction in instructions} - categories.keys())
    if missing:
        raise RunError(f"{len(missing)} scored photos (first {missing[0]}) are not in the folder's {META}")
    members = tally.group_members(instructions, lambda instruction: categories[photo(instruction)])
    return {category: {"instructions": len(rows), **{name: tally.percent(hits[name][rows]) for name in SCORES},
                       "median_centre_px": round(float(np.nanmedian(distance[rows])), 2)}
            for category, rows in members.items()}


def main(argv=None) -> int:
    return commands.run_command(define_scored_run_flags, categories_command, argv,
                                prog="python -m kosmos_jax.diagnostics.categories", doc=__doc__)


def categories_command(args) -> None:
    try:
        run, step, records, protocol, folder, answers = scored_folder_answers(
            args, "categories are known for a scored synthetic folder only")
        figures = by_category(records, answers, run.format_config, protocol, photo_categories(folder))
    except RunError as error:
        raise SystemExit(f"error: {error}") from None
    if args.json:
        print(json.dumps({"step": step, "scored": args.scored, "categories": figures}))
        return
    print(f"step {step}, single-photo instructions of {args.scored} by category: accuracy in percent")
    print(f"{'category':<20}{'instructions':>13}" + "".join(f"{name:>13}" for name in SCORES) + f"{'centre px':>11}")
    for category, row in sorted(figures.items(), key=lambda item: item[1]["model"]):
        print(f"{category:<20}{row['instructions']:>13}" + "".join(f"{row[name]:>13.2f}" for name in SCORES)
              + f"{row['median_centre_px']:>11.2f}")


if __name__ == "__main__":
    sys.exit(main())
