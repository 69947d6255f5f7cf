"""Two runs' answers to the same instructions, paired: how many each got right that the other did not.

    python scripts/paired_runs.py --baseline=demo_out/run --candidate=runs/ft/px224_s0 \
        [--scored=cornell-synthetic-300-seed7] [--step=N] [--zoomed]
    python scripts/paired_runs.py --baseline=demo_out/run --candidate=runs/evaluate/soup/cornell-synthetic-300-seed7/answers.jsonl

Either side may be an answers.jsonl file itself (what `evaluate --pretrained=FOLDER --cornell=...` writes under its --out).

Reads the answers.jsonl that `python -m kosmos_jax.evaluate --cornell=...` wrote for each run (the same folder and
kinds: the pairs are checked example by example) and prints one JSON line per scene (single photos, mosaics): the
instructions, each run's right answers, those right only for one of them, and McNemar's z, (only candidate - only
baseline) / sqrt(their sum): a difference between two runs on the same instructions beyond what chance splits of
the discordant pairs give (|z| > 2 at about 5%). --zoomed adds a line for the mosaics as the mosaic zoom answered
them (both runs scored with evaluate --mosaic_zoom). Every part row of an instruction carries the instruction's result;
the first row of each stands for it.
"""

import argparse
import json
import math
import pathlib
import sys

from kosmos_jax.diagnostics.answer_errors import answer_rows, read_answers
from kosmos_jax.workdir.checkpoints import chosen_step
from kosmos_jax.workdir.files import RunError


def instruction_results(rows: list[dict], zoomed: bool = False) -> dict[int, tuple]:
    """{first example index: (kind, scene, target text, right)} of each instruction in evaluate's answer rows
    (an instruction's parts are consecutive rows, each part once). `zoomed`: the mosaic instructions alone,
    right as the mosaic zoom answered them (evaluate --mosaic_zoom's zoom_correct), scene "multi, zoomed"."""
    if zoomed:
        rows = [{**row, "scene": "multi, zoomed", "correct": row["zoom_correct"]} for row in rows if "zoom_correct" in row]
        if not rows:
            raise RunError("no answer row holds zoom_correct: score the run with evaluate --mosaic_zoom and mosaics")
    results, key, parts = {}, None, set()
    for row in rows:
        row_key = (row["kind"], tuple(row["photo_ids"]), row["instruction"])
        if row_key != key or row["part"] in parts:
            results[row["example"]] = (row["kind"], row["scene"], row["target_text"], bool(row["correct"]))
            key, parts = row_key, set()
        parts.add(row["part"])
    return results


def mcnemar_z(only_candidate: int, only_baseline: int) -> float:
    """McNemar's z of two answer sets on the same instructions, from their discordant pairs (0 when none)."""
    discordant = only_candidate + only_baseline
    return round((only_candidate - only_baseline) / math.sqrt(discordant), 2) if discordant else 0.0


def paired(baseline: dict, candidate: dict) -> list[dict]:
    if baseline.keys() != candidate.keys() or any(baseline[k][:3] != candidate[k][:3] for k in baseline):
        raise RunError("the two runs did not answer the same instructions (another folder, kinds or tokenizer)")
    out = []
    for scene in sorted({value[1] for value in baseline.values()}):
        keys = [k for k, value in baseline.items() if value[1] == scene]
        only_candidate = sum(candidate[k][3] and not baseline[k][3] for k in keys)
        only_baseline = sum(baseline[k][3] and not candidate[k][3] for k in keys)
        out.append({"scene": scene, "instructions": len(keys), "baseline_right": sum(baseline[k][3] for k in keys),
                    "candidate_right": sum(candidate[k][3] for k in keys), "only_candidate": only_candidate,
                    "only_baseline": only_baseline,
                    "mcnemar_z": mcnemar_z(only_candidate, only_baseline)})
    return out


def answers_of(path: pathlib.Path, step: int | None, scored: str) -> list[dict]:
    """The answer rows of an answers.jsonl file, or of a run's workdir at `step` (None: its newest) on `scored`."""
    if path.is_file():
        return answer_rows(path)
    return read_answers(path, chosen_step(path, step), scored)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--baseline", required=True)
    parser.add_argument("--candidate", required=True)
    parser.add_argument("--scored", default="cornell-synthetic-300-seed7")
    parser.add_argument("--step", type=int, default=None, help="checkpoint step (default: each run's newest)")
    parser.add_argument("--zoomed", action="store_true", help="also a line for the mosaics as the zoom answered them")
    args = parser.parse_args()
    try:
        answers = [answers_of(pathlib.Path(side), args.step, args.scored) for side in (args.baseline, args.candidate)]
        lines = paired(*(instruction_results(rows) for rows in answers))
        if args.zoomed:
            lines += paired(*(instruction_results(rows, zoomed=True) for rows in answers))
    except RunError as error:
        sys.exit(f"error: {error}")
    for line in lines:
        print(json.dumps(line))


if __name__ == "__main__":
    main()
