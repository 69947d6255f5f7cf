"""From an INSTRUCT-GRASP `Sample` to text examples: which grasp, which fields, which words.

Settings (`FormatConfig`), after the paper's ablations (Tables IV and V):
- representation: xya | xywha | tlbra | tlbra_patch (text from `kosmos_jax.grasp_text`).
- angle_code: the 256-bin code "a_77" or radians "a_-0.52".
- individual: True gives each grasp as two examples, its location (the centre in XYA) and its
  angle (the paper's best); False gives one joint example with the whole grasp. In individual
  mode the field's cue ("Grasp center point coordinates:", "Grasp rotation angle in radians:")
  ends the prompt and only the value is the target, so a model is asked for one field at a time;
  `prompt_cues` lists the cues a decoder puts after the instruction.
- loss_on: "target" (the answer and </s>) or "instruction" (every text token after </image>).
- target_grasp: which of a sample's answering grasps become targets (`kosmos_jax.text.target_rows`).
An angle instruction already states the angle, so its answer is the location only.

The text of a location is `grasp_text.format_grasp`'s, less the angle: it keeps every printed
value inside what the parser accepts (a centre at x = 223.6 prints as x_223, not x_224); `grasp`
keeps the unrounded values.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from kosmos_jax import grasp_text
from kosmos_jax.grasp_text import split_cue  # also formatter.split_cue, for the decoder's grammar
from kosmos_jax.text.target_rows import TARGET_CHOICES, chosen_rows

LOSS_MODES = ("target", "instruction")
OVERFLOW_MODES = ("error", "truncate")
PARTS = ("grasp", "location", "angle")

# which of (x, y, w, h, theta) the text of each part states, by representation
_LOCATION_FIELDS = {
    "xya": (1, 1, 0, 0, 0),
    "xywha": (1, 1, 1, 1, 0),
    "tlbra": (1, 1, 0, 0, 0),  # w, h are not recoverable from the box near 45 degrees
    "tlbra_patch": (1, 1, 0, 0, 0),
}
_ANGLE_FIELDS = (0, 0, 0, 0, 1)


@dataclasses.dataclass(frozen=True)
class FormatConfig:
    representation: str = "xya"
    angle_code: bool = True
    individual: bool = True
    loss_on: str = "target"
    target_grasp: str = "first"
    image_size: int = 224
    max_length: int = 128
    overflow: str = "error"

    def __post_init__(self):
        grasp_text.check_representation(self.representation)
        for name, value, valid in (
            ("loss_on", self.loss_on, LOSS_MODES),
            ("overflow", self.overflow, OVERFLOW_MODES),
            ("target_grasp", self.target_grasp, TARGET_CHOICES),
        ):
            if value not in valid:
                raise ValueError(f"unknown {name} {value!r}; expected one of {valid}")
        if self.image_size < 1:
            raise ValueError(f"image_size must be positive, got {self.image_size}")


@dataclasses.dataclass(frozen=True)
class TextExample:
    """One formatted example: the prompt is instruction + cue, the target is value.

    grasp: the (x, y, w, h, theta) the target text was made from; grasp_mask: which of the five
    the text states. answers: every grasp that answers the instruction ([N, 5], for evaluation).
    """

    kind: str
    scene: str
    part: str
    instruction: str
    cue: str
    value: str
    grasp: np.ndarray
    grasp_mask: np.ndarray
    answers: np.ndarray
    image: np.ndarray
    photo_ids: tuple[str, ...]
    object_ids: tuple[int | None, ...]
    target: int = 0

    @property
    def target_text(self) -> str:
        """The answer as the grasp text of `kosmos_jax.grasp_text` (cue and value)."""
        return target_text(self.cue, self.value)

    @property
    def text(self) -> str:
        """Instruction, cue and value as the tokens spell them (single spaces between)."""
        return " ".join(s for s in (self.instruction, self.cue, self.value) if s)


def check_part(part: str) -> str:
    """`part` if it is one of PARTS; ValueError naming it otherwise."""
    if part not in PARTS:
        raise ValueError(f"unknown part {part!r}; expected one of {PARTS}")
    return part


def target_text(cue: str, value: str) -> str:
    """The answer text of a part: "cue value", or the value alone when there is no cue (joint mode)."""
    return f"{cue} {value}" if cue else value


def location_text(grasp, config: FormatConfig) -> str:
    """The location part of a grasp's text (all of it but the angle)."""
    full = grasp_text.format_grasp(grasp, config.representation, config.angle_code, config.image_size)
    angle = grasp_text.format_angle(grasp[4], config.angle_code)
    if not full.endswith(" " + angle):
        raise AssertionError(f"grasp text {full!r} does not end with its angle {angle!r}")
    return full[: -len(angle) - 1]


def grasp_parts(grasp, answer: str, config: FormatConfig) -> list[tuple[str, str, str, np.ndarray]]:
    """(part, cue, value, grasp_mask) of each example one grasp gives."""
    if answer not in ("grasp", "centre"):
        raise ValueError(f"unknown answer {answer!r}; expected 'grasp' or 'centre'")
    location = location_text(grasp, config)
    angle = grasp_text.format_angle(float(grasp[4]), config.angle_code)
    location_mask = np.array(_LOCATION_FIELDS[config.representation], bool)
    if answer == "centre" or config.individual:
        cue, value = split_cue(location) if config.individual else ("", location)
        parts = [("location", cue, value, location_mask)]
        if answer == "grasp":
            parts.append(("angle", *split_cue(angle), np.array(_ANGLE_FIELDS, bool)))
        return parts
    return [("grasp", "", f"{location} {angle}", location_mask | np.array(_ANGLE_FIELDS, bool))]


def prompt_cues(config: FormatConfig, answer: str = "grasp") -> list[tuple[str, str]]:
    """(part, cue) a decoder appends to the instruction; one ("grasp", "") in joint mode."""
    probe = np.array([config.image_size / 2, config.image_size / 2, 10.0, 10.0, 0.0])
    return [(part, cue) for part, cue, _, _ in grasp_parts(probe, answer, config)]


def format_sample(sample, config: FormatConfig, rng: np.random.Generator | None = None) -> list[TextExample]:
    """The text examples of one `kosmos_jax.instruct.Sample`."""
    answers = np.asarray(sample.grasps, np.float64)
    if answers.ndim != 2 or answers.shape[1] != 5 or answers.shape[0] == 0:
        raise ValueError(f"sample of photos {sample.photo_ids} has no grasps to answer with (shape {answers.shape})")
    examples = []
    for row in chosen_rows(answers, config.target_grasp, rng):
        grasp = answers[row]
        for part, cue, value, mask in grasp_parts(grasp, sample.answer, config):
            examples.append(
                TextExample(
                    kind=sample.kind,
                    scene=sample.scene,
                    part=part,
                    instruction=" ".join(str(sample.instruction).split()),
                    cue=cue,
                    value=value,
                    grasp=grasp.copy(),
                    grasp_mask=mask,
                    answers=answers,
                    image=sample.image,
                    photo_ids=tuple(sample.photo_ids),
                    object_ids=tuple(sample.object_ids),
                    target=int(sample.target),
                )
            )
    return examples


def parse_target(text: str, part: str, config: FormatConfig) -> grasp_text.ParsedGrasp:
    """Parse a target text (cue and value) of one part back to (x, y, w, h, theta), NaN where unstated."""
    check_part(part)
    if part == "grasp":
        return grasp_text.parse_grasp(text, config.representation, config.angle_code, config.image_size)
    if part == "angle":
        theta, why = grasp_text.parse_angle(text, config.angle_code)
        if why:
            return grasp_text.ParsedGrasp(False, np.full(5, np.nan), why)
        return grasp_text.ParsedGrasp(True, np.array([np.nan] * 4 + [theta]))
    # a location alone: borrow the grasp parser with a neutral angle, then forget that angle
    probe = text + " " + grasp_text.format_angle(0.0, config.angle_code)
    parsed = grasp_text.parse_grasp(probe, config.representation, config.angle_code, config.image_size)
    if not parsed.ok:
        return parsed
    grasp = parsed.grasp.copy()
    grasp[4] = np.nan
    if config.representation == "tlbra":
        grasp[2:4] = np.nan  # the parser's w, h assumed the borrowed angle
    return grasp_text.ParsedGrasp(True, grasp)


def corpus(examples: Sequence[TextExample]) -> list[str]:
    """The sentences a tokenizer is trained on: each example's text."""
    return [example.text for example in examples]
