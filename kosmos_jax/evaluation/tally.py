"""Grasps of instructions -> rectangle-metric successes -> accuracy overall, per kind and per scene,
each with the number of instructions and of examples behind it; and its Markdown table.

An answer that did not parse is a miss: its grasp is NaN, which the metric never counts as a
success, and no ground truth ever stands in for it (whatever the protocol).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from kosmos_jax.evaluation.instructions import Instruction
from kosmos_jax.evaluation.scoring import WH_POLICY
from kosmos_jax.metrics import grasp_success


def successes(instructions: Sequence[Instruction], grasps: np.ndarray, protocol: str,
              backend: str = "exact") -> np.ndarray:
    """bool [G]: does grasp i, (x, y, theta), hit a ground truth of instruction i? w and h follow the
    protocol (honest: each ground truth's own; paper: the widest opening and the mean jaw)."""
    if not instructions:
        return np.zeros(0, bool)
    width = max(len(i.answers) for i in instructions)
    gts = np.zeros((len(instructions), width, 5), np.float32)
    mask = np.zeros((len(instructions), width), bool)
    for row, instruction in enumerate(instructions):
        gts[row, :len(instruction.answers)] = instruction.answers
        mask[row, :len(instruction.answers)] = True
    found = grasp_success(np.asarray(grasps, np.float32), gts, mask, backend=backend, wh_policy=WH_POLICY[protocol])
    return np.asarray(found)


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


def group_figures(instructions: Sequence[Instruction], success: np.ndarray, free_success: np.ndarray,
                  free_failed: np.ndarray, label) -> dict[str, dict]:
    """{group: {accuracy, instructions, examples, unconstrained_accuracy, unconstrained_parse_failures}}
    with `label(instruction)` naming each instruction's group; `free_failed` [G] counts each
    instruction's unconstrained answers that did not parse."""
    return {name: {**_figures(instructions, success, idx), "unconstrained_accuracy": percent(free_success[idx]),
                   "unconstrained_parse_failures": int(free_failed[idx].sum())}
            for name, idx in group_members(instructions, label).items()}


def markdown(results: dict) -> str:
    """The results as a Markdown table: overall, per scene, per kind. Results without an
    unconstrained decoding (a baseline's) get the accuracy column alone."""
    decoded = "unconstrained" in results
    who = "" if decoded else f"{results['model']}, "
    head = (f"{who}Step {results['step']}, {results['split']} ({results['examples']} examples, "
            f"{results['instructions']} instructions), protocol `{results['protocol']}`, IoU `{results['backend']}`; "
            + ("accuracy in percent, a parse failure counts as a miss.\n\n" if decoded
               else "accuracy in percent of one predicted grasp a view.\n\n"))
    if decoded:
        lines = ["| group | instructions | examples | accuracy (constrained) | accuracy (unconstrained) "
                 "| unconstrained parse failures |", "|---|---:|---:|---:|---:|---:|"]
        free = results["unconstrained"]
        extra = {"unconstrained_accuracy": free["accuracy"], "unconstrained_parse_failures": free["parse_failures"]}
    else:
        lines = ["| group | instructions | examples | accuracy |", "|---|---:|---:|---:|"]
        extra = {}
    overall = {"accuracy": results["accuracy"], "instructions": results["instructions"],
               "examples": results["examples"], **extra}
    groups = [("all", overall)] + [(f"scene {k}", v) for k, v in results["by_scene"].items()] \
        + [(f"kind {k}", v) for k, v in results["by_kind"].items()]
    for name, g in groups:
        cells = f"| {name} | {g['instructions']} | {g['examples']} | {g['accuracy']:.2f} |"
        if decoded:
            cells += f" {g['unconstrained_accuracy']:.2f} | {g['unconstrained_parse_failures']} |"
        lines.append(cells)
    return head + "\n".join(lines) + "\n"
