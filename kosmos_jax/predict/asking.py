"""An instruction -> the prompts the model is asked, laid out as training laid out its examples.

The prompt of each part is layout.py's: <s><image> 64 slots </image>, the instruction encoded on
its own, then the part's cue encoded on its own (individual outputs; none in joint mode), so the
model sees the tokens it was trained on up to where its answer starts. What is asked follows the
evaluation (scoring.questions): a whole grasp, or the centre alone for an angle instruction
(one that states its angle as a code, "... a rotation angle of a_156 radians."), whose angle is
the one it states. No instruction at all (None) is KOSMOS-E's NON kind: the prompt holds the image
and the cue only, as the build writes NON examples; an empty string is refused as a likely mistake.

An instruction whose prompt and longest answer do not fit in the model's context (its position
embeddings) is refused before anything is decoded.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from kosmos_jax.predict.errors import InstructionError
from kosmos_jax.scoring.instructions import instructed_angle
from kosmos_jax.scoring.prompts import written_prompt
from kosmos_jax.scoring.questions import Question
from kosmos_jax.text import formatter, layout
from kosmos_jax.text.tokenizer import Tokenizer


@dataclasses.dataclass(frozen=True)
class Prompt:
    question: Question
    tokens: np.ndarray  # int32 [L]
    image_mask: np.ndarray  # bool [L]


@dataclasses.dataclass(frozen=True)
class Asked:
    instruction: str  # whitespace collapsed, as the build writes it; "" for NON (no instruction)
    answer: str  # "grasp", or "centre" for an angle instruction
    prompts: tuple[Prompt, ...]  # one per part, in the order formatter.prompt_cues lists them


def clean_instruction(instruction: str | None) -> str:
    """The instruction with its whitespace collapsed; "" for None (NON)."""
    if instruction is None:
        return ""
    if not isinstance(instruction, str):
        raise InstructionError(f"an instruction is text, not {type(instruction).__name__}")
    cleaned = " ".join(instruction.split())
    if not cleaned:
        raise InstructionError("the instruction is empty (or only whitespace); say what to grasp, e.g. "
                               "'Grasp the red mug.', or give none (None; the command: no --instruction) for "
                               "KOSMOS-E's NON kind")
    return cleaned


def answer_kind(instruction: str) -> str:
    """"centre" when the instruction states one angle code (its answer is the location only)."""
    try:
        instructed_angle(instruction)
    except ValueError:
        return "grasp"
    return "centre"


def ask(instruction, tokenizer: Tokenizer, config: formatter.FormatConfig,
        questions: dict[tuple[str, str], Question], context: int) -> Asked:
    """The prompts of `instruction`; InstructionError if it is empty or too long for `context` tokens."""
    cleaned = clean_instruction(instruction)
    answer = answer_kind(cleaned)
    prompts = []
    for part, cue in formatter.prompt_cues(config, answer):
        question = questions[(answer, part)]
        ids, image_mask = written_prompt(tokenizer, cleaned, cue)
        needed = len(ids) + question.max_new_tokens
        if needed > context:
            raise InstructionError(
                f"the instruction is too long: its {len(cleaned.split())} words take {len(ids) - layout.PREFIX_LENGTH} tokens, and "
                f"with the image prefix ({layout.PREFIX_LENGTH}) and the answer ({question.max_new_tokens}) the "
                f"prompt needs {needed} tokens, more than the model's context of {context}")
        prompts.append(Prompt(question, ids, image_mask))
    return Asked(cleaned, answer, tuple(prompts))
