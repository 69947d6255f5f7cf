"""Examples -> instructions: which examples answer one instruction, and the grasp their answers make.

In individual mode the build writes an instruction as consecutive examples of one sample: its
location, then its angle (formatter.grasp_parts); an angle instruction gives the location only,
since the instruction states the angle. In joint mode one example holds the whole grasp. The
paper scores one grasp per instruction, so the centre answer and the angle answer of the same
instruction are combined before the rectangle metric sees them.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Mapping, Sequence

import numpy as np

from kosmos_jax import geometry
from kosmos_jax.dataset.samples import MULTI_PREFIX
from kosmos_jax.grasp_text import ParsedGrasp
from kosmos_jax.instruct.kinds import ANSWERS

_INSTRUCTED_CODE = re.compile(r"\ba_([0-9]+)\b")


@dataclasses.dataclass(frozen=True)
class Instruction:
    kind: str  # the kind label: "non", "colour", "multi-colour", ...
    scene: str  # "single" (NON included) or "multi" (a mosaic)
    instruction: str
    examples: Mapping[str, int]  # part ("grasp", "location", "angle") -> index of its example
    answers: np.ndarray  # [N, 5] every grasp that answers the instruction

    @property
    def answer(self) -> str:
        """What the instruction asks for: "grasp", or "centre" (an angle instruction)."""
        return ANSWERS[self.kind.removeprefix(MULTI_PREFIX)]


def text(value) -> str:
    """A stored string field (bytes when read back from the files) as str."""
    return value.decode() if isinstance(value, bytes) else str(value)


def _key(record: Mapping) -> tuple:
    return (tuple(text(p) for p in record["photo_ids"]), text(record["kind"]), text(record["scene"]),
            text(record["instruction"]), int(record["target"]))


def _instruction(records: Sequence[Mapping], parts: dict[str, int]) -> Instruction:
    first = records[min(parts.values())]
    scene = "multi" if text(first["scene"]) == "multi" else "single"
    kind = text(first["kind"])
    made = Instruction(MULTI_PREFIX + kind if scene == "multi" else kind, scene, text(first["instruction"]),
                       dict(parts), np.asarray(first["answers"], np.float32).reshape(-1, 5))
    needed = ({"location"},) if made.answer == "centre" else ({"grasp"}, {"location", "angle"})
    if set(parts) not in needed:
        expected = " or ".join(str(sorted(n)) for n in needed)
        raise ValueError(f"examples {sorted(parts.values())} ({made.kind} instruction {made.instruction!r}) hold the "
                         f"parts {sorted(parts)}; a {made.answer} answer is {expected}")
    return made


def group_instructions(records: Sequence[Mapping]) -> list[Instruction]:
    """The instructions of a split's records, in order: consecutive records of the same sample
    (photos, kind, scene, sentence, target) whose parts do not repeat belong to one instruction."""
    groups: list[dict[str, int]] = []
    last_key = None
    for index, record in enumerate(records):
        key, part = _key(record), text(record["part"])
        if key != last_key or part in groups[-1]:
            groups.append({})
        groups[-1][part] = index
        last_key = key
    return [_instruction(records, parts) for parts in groups]


def instructed_angle(instruction: str) -> float:
    """The angle an angle instruction states ("... with a rotation angle of a_156 radians.")."""
    found = _INSTRUCTED_CODE.findall(instruction)
    if len(found) != 1:
        raise ValueError(f"angle instruction {instruction!r} does not state one angle code a_<k>")
    return float(geometry.decode_angle(np.int64(found[0])))


def combine_asked(answer: str, instruction: str, parsed: Mapping[str, ParsedGrasp]) -> np.ndarray:
    """combine() for answers to an instruction asked from text, with no stored examples or ground truth
    (the predict command's, the mosaic zoom's): `answer` "grasp", or "centre" when `instruction` states
    its angle."""
    asked = Instruction("angle" if answer == "centre" else "non", "single", instruction, dict.fromkeys(parsed, 0),
                        np.zeros((0, 5), np.float32))
    return combine(asked, parsed)


def combine(instruction: Instruction, parsed: Mapping[str, ParsedGrasp]) -> np.ndarray:
    """(x, y, theta) of the instruction's answers, NaN where any of them did not parse: the centre
    of the grasp or location answer, the angle of the grasp or angle answer, or the instructed
    angle when the instruction states it."""
    if not all(parsed[part].ok for part in instruction.examples):
        return np.full(3, np.nan)
    centre = parsed["grasp" if "grasp" in instruction.examples else "location"].grasp[:2]
    if instruction.answer == "centre":
        theta = instructed_angle(instruction.instruction)
    else:
        theta = parsed["grasp" if "grasp" in instruction.examples else "angle"].grasp[4]
    return np.array([centre[0], centre[1], theta], np.float64)
