"""Grasps of instructions -> rectangle-metric successes -> accuracy overall, per kind and per scene,
each with the number of instructions and of examples behind it; how many different answers were
given (distinct); whether the answered angle fits the ground truth nearest the answered centre
(angle_errors, angle_fit); and its Markdown table.

An answer that did not parse is a miss: its grasp is NaN, which the metric never counts as a
success, and no ground truth ever stands in for it (whatever the protocol).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from kosmos_jax import geometry
from kosmos_jax.grasp_text import ParsedGrasp
from kosmos_jax.metrics import grasp_success
from kosmos_jax.scoring.fold_scores import metric_settings
from kosmos_jax.scoring.instructions import Instruction, combine


def padded_answers(instructions: Sequence[Instruction]) -> tuple[np.ndarray, np.ndarray]:
    """[G, N, 5] every instruction's answer grasps, padded to the most answers, and their [G, N] mask."""
    width = max(len(i.answers) for i in instructions)
    grasps = np.zeros((len(instructions), width, 5), np.float32)
    mask = np.zeros((len(instructions), width), bool)
    for row, instruction in enumerate(instructions):
        grasps[row, :len(instruction.answers)] = instruction.answers
        mask[row, :len(instruction.answers)] = True
    return grasps, mask


def successes(instructions: Sequence[Instruction], grasps: np.ndarray, protocol: str,
              backend: str = "exact") -> np.ndarray:
    """bool [G]: does grasp i, (x, y, theta), hit a ground truth of instruction i? w and h follow the
    protocol (honest: each ground truth's own; paper: the widest opening and the mean jaw; public, a
    baseline's: its own, grasps [G, 5], with the pixel-count IoU)."""
    if not instructions:
        return np.zeros(0, bool)
    gts, mask = padded_answers(instructions)
    wh_policy, backend = metric_settings(protocol, backend)
    found = grasp_success(np.asarray(grasps, np.float32), gts, mask, backend=backend, wh_policy=wh_policy)
    return np.asarray(found)


ANGLE_LIMIT_DEG = 30.0  # the rectangle metric's angle limit (metrics.grasp_success's default)


def angle_errors(instructions: Sequence[Instruction], grasps: np.ndarray) -> np.ndarray:
    """float [G]: each grasp's angle error in degrees against the ground truth whose centre lies
    nearest the grasp's centre (the angle judged where the answer put the grasp, whatever its IoU);
    inf where the grasp did not parse. An angle the instruction itself states counts like an answered one."""
    errors = np.full(len(instructions), np.inf)
    for row, (instruction, grasp) in enumerate(zip(instructions, np.asarray(grasps, np.float64))):
        if np.isfinite(grasp).all() and len(instruction.answers):
            nearest = instruction.answers[np.argmin(np.hypot(*(instruction.answers[:, :2] - grasp[:2]).T))]
            errors[row] = np.degrees(geometry.angle_difference(grasp[2], float(nearest[4])))
    return errors


def angle_fit(errors: np.ndarray) -> dict:
    """{within_30_deg: percent of `angle_errors` within the metric's limit (an unparsed grasp is a miss),
    instructions, median_deg: their median, the unparsed left out (None when none parsed)}."""
    answered = errors[np.isfinite(errors)]
    return {"within_30_deg": percent(errors <= ANGLE_LIMIT_DEG), "instructions": len(errors),
            "median_deg": round(float(np.median(answered)), 2) if len(answered) else None}


def percent(hits: np.ndarray) -> float:
    return round(100.0 * float(np.mean(hits)), 4) if len(hits) else float("nan")


def group_members(instructions: Sequence[Instruction], label) -> dict[str, list[int]]:
    """{group: indices of its instructions}, `label(instruction)` naming each instruction's group."""
    rows: dict[str, list[int]] = {}
    for index, instruction in enumerate(instructions):
        rows.setdefault(label(instruction), []).append(index)
    return dict(sorted(rows.items()))


def _figures(instructions: Sequence[Instruction], success: np.ndarray, idx: list[int]) -> dict:
    return {"accuracy": percent(success[idx]), "instructions": len(idx),
            "examples": int(sum(len(instructions[i].examples) for i in idx))}


def group_accuracy(instructions: Sequence[Instruction], success: np.ndarray, label) -> dict[str, dict]:
    """{group: {accuracy, instructions, examples}}: a predictor with one answer an instruction (a baseline)."""
    return {name: _figures(instructions, success, idx) for name, idx in group_members(instructions, label).items()}


def group_figures(instructions: Sequence[Instruction], success: np.ndarray, free_success: np.ndarray | None,
                  free_failed: np.ndarray | None, label, ceiling: np.ndarray | None = None) -> dict[str, dict]:
    """{group: {accuracy, instructions, examples[, unconstrained_accuracy, unconstrained_parse_failures]
    [, target_ceiling]}} with `label(instruction)` naming each instruction's group; `free_failed` [G]
    counts each instruction's unconstrained answers that did not parse (both None: no unconstrained
    decoding); `ceiling` [G], when given, says whether each instruction's own targets, scored as answers, hit."""
    def free(idx):
        if free_success is None:
            return {}
        return {"unconstrained_accuracy": percent(free_success[idx]),
                "unconstrained_parse_failures": int(free_failed[idx].sum())}

    return {name: {**_figures(instructions, success, idx), **free(idx),
                   **({} if ceiling is None else {"target_ceiling": percent(ceiling[idx])})}
            for name, idx in group_members(instructions, label).items()}


def distinct(instructions: Sequence[Instruction], answers: Mapping[int, tuple[str, ParsedGrasp]]) -> dict[str, int]:
    """How many different answers the examples of `instructions` got ({example index: (text, parse)}):
      texts    distinct answer texts, over every part (parsed or not);
      centres  distinct (x, y) of the grasp or location answers that parsed;
      angles   distinct angles of the grasp or angle answers that parsed (an angle an instruction
               states is no answer);
      grasps   distinct (x, y, theta) of the instructions whose answers all parsed, combined as the
               metric sees them (instructions.combine).
    One value repeated for every instruction is 1 in its field, a fixed point of the model."""
    texts, centres, angles = set(), set(), set()
    for instruction in instructions:
        for part, index in instruction.examples.items():
            text, parsed = answers[index]
            texts.add(text)
            if not parsed.ok:
                continue
            if part in ("grasp", "location"):
                centres.add(tuple(np.asarray(parsed.grasp[:2], np.float64).tolist()))
            if part in ("grasp", "angle"):
                angles.add(float(parsed.grasp[4]))
    grasps = [combine(instruction, {part: answers[i][1] for part, i in instruction.examples.items()})
              for instruction in instructions]
    whole = {tuple(np.asarray(grasp, np.float64).tolist()) for grasp in grasps if np.isfinite(grasp).all()}
    return {"texts": len(texts), "centres": len(centres), "angles": len(angles), "grasps": len(whole)}


def distinct_text(counts: Mapping[str, int]) -> str:
    """"12 texts, 10 centres, 5 angles, 12 grasps"."""
    return ", ".join(f"{value} {name}" for name, value in counts.items())


def markdown(results: dict) -> str:
    """The results as a Markdown table: overall, per scene, per kind, with the target ceiling beside
    the accuracy where the results have one, and a line of distinct answers and targets where they
    have it. Results of no decoding (a baseline's) get the accuracy column alone; decoded results
    without the unconstrained decoding (asked not to make it) get no unconstrained columns."""
    free = "unconstrained" in results
    decoded = free or "constrained" in results
    ceiling = "target_ceiling" in results
    who = "" if decoded else f"{results['model']}, "
    head = (f"{who}Step {results['step']}, {results['split']} ({results['examples']} examples, "
            f"{results['instructions']} instructions), protocol `{results['protocol']}`, IoU `{results['backend']}`; "
            + ("accuracy in percent, a parse failure counts as a miss" if decoded
               else "accuracy in percent of one predicted grasp a view")
            + ("; target ceiling: the examples' own targets scored as answers.\n\n" if ceiling else ".\n\n"))
    if decoded:
        ceiling_head = " target ceiling |" if ceiling else ""
        lines = ["| group | instructions | examples | accuracy (constrained) |" + ceiling_head
                 + (" accuracy (unconstrained) | unconstrained parse failures |" if free else ""),
                 "|---|---:|---:|---:|" + ("---:|" if ceiling else "") + ("---:|---:|" if free else "")]
        extra = {"unconstrained_accuracy": results["unconstrained"]["accuracy"],
                 "unconstrained_parse_failures": results["unconstrained"]["parse_failures"]} if free else {}
    else:
        lines = ["| group | instructions | examples | accuracy |", "|---|---:|---:|---:|"]
        extra = {}
    overall = {"accuracy": results["accuracy"], "instructions": results["instructions"],
               "examples": results["examples"], **extra,
               **({"target_ceiling": results["target_ceiling"]} if ceiling else {})}
    groups = [("all", overall)] + [(f"scene {k}", v) for k, v in results["by_scene"].items()] \
        + [(f"kind {k}", v) for k, v in results["by_kind"].items()]
    for name, g in groups:
        cells = f"| {name} | {g['instructions']} | {g['examples']} | {g['accuracy']:.2f} |"
        if decoded and ceiling:
            cells += f" {g['target_ceiling']:.2f} |" if "target_ceiling" in g else " |"
        if free:
            cells += f" {g['unconstrained_accuracy']:.2f} | {g['unconstrained_parse_failures']} |"
        lines.append(cells)
    table = head + "\n".join(lines) + "\n"
    if "distinct" in results:
        spread = results["distinct"]
        table += (f"\nDistinct (constrained) answers: {distinct_text(spread['answers'])}; "
                  f"targets: {distinct_text(spread['targets'])}.\n")
    if "angle_at_centre" in results:
        fit = results["angle_at_centre"]
        table += (f"\nAngle at the answered centre: {fit['within_30_deg']:.2f}% of {fit['instructions']} instructions "
                  f"within 30 degrees of the ground truth nearest the answered centre (median {fit['median_deg']}).\n")
    if "mosaic_zoom" in results and "multi" in results["mosaic_zoom"]["by_scene"]:
        zoomed, first = results["mosaic_zoom"], results["by_scene"]["multi"]
        table += (f"\nMosaic zoom (each mosaic instruction answered again on the quadrant its first answer chose): "
                  f"{zoomed['by_scene']['multi']['accuracy']:.2f}% of {first['instructions']} mosaic instructions "
                  f"against {first['accuracy']:.2f}% in one pass ({zoomed['mosaics_right_only_zoomed']} right only "
                  f"zoomed, {zoomed['mosaics_right_only_first']} only in one pass); all {zoomed['accuracy']:.2f}%.\n")
    return table
