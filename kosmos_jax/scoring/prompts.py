"""Prompts from stored examples: the tokens the model was trained on, up to where the answer starts;
and the stored answer tokens after it, which the evaluation scores as if a model had generated them
(model_scores.py: the target ceiling).

layout.py writes <s><image> slots </image> instruction cue value </s>, each text segment encoded
on its own, so the value is a token suffix: the prompt is the stored tokens before it (the cue
included in individual mode), with the stored image mask. Batches are left-padded (decode.py).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from kosmos_jax.scoring.instructions import text
from kosmos_jax.text import layout
from kosmos_jax.text.tokenizer import Tokenizer


def answer_value(record: Mapping, cue: str) -> str:
    """The value of a record's target text (what follows `cue`, or all of it without a cue)."""
    target = text(record["target_text"])
    if not cue:
        return target
    if not target.startswith(cue + " "):
        raise ValueError(f"target text {target!r} of a {text(record['part'])} example does not start with "
                         f"its cue {cue!r}")
    return target[len(cue) + 1:]


def _answer_start(record: Mapping, tokenizer: Tokenizer, cue: str) -> tuple[np.ndarray, int]:
    """(the record's stored tokens, where its value starts in them)."""
    length = int(record["length"])
    tokens = np.asarray(record["tokens"])[:length]
    value = tokenizer.encode(answer_value(record, cue))
    start = length - 1 - len(value)
    if start < 0 or tokens[-1] != tokenizer.eos_id or tokens[start:-1].tolist() != value:
        raise ValueError(f"stored tokens of a {text(record['part'])} example of photos "
                         f"{[text(p) for p in record['photo_ids']]} do not end with its value and </s>: "
                         "another tokenizer, or truncated")
    return tokens, start


def prompt(record: Mapping, tokenizer: Tokenizer, cue: str) -> tuple[np.ndarray, np.ndarray]:
    """(token ids, image mask) of the record's prompt: its stored tokens before the value."""
    tokens, start = _answer_start(record, tokenizer, cue)
    return tokens[:start], np.asarray(record["image_mask"], bool)[:start]


def written_prompt(tokenizer: Tokenizer, instruction: str, cue: str) -> tuple[np.ndarray, np.ndarray]:
    """(token ids, image mask) of a prompt made from text, as the build lays out a stored one: the image
    prefix, then the instruction ("" for NON: none) and the cue, each encoded on its own."""
    ids = layout.prefix_ids(tokenizer) + [i for segment in (instruction, cue) if segment
                                          for i in tokenizer.encode(segment)]
    return np.asarray(ids, np.int32), layout.slots_mask(len(ids))


def target_ids(record: Mapping, tokenizer: Tokenizer, cue: str) -> np.ndarray:
    """The record's stored tokens after its prompt (its value and </s>): what a model that reproduced
    its target would generate."""
    tokens, start = _answer_start(record, tokenizer, cue)
    return tokens[start:]


def left_padded(prompts: Sequence[tuple[np.ndarray, np.ndarray]], length: int, pad_id: int):
    """(ids, attention mask, image mask) [len(prompts), length], each prompt at the right end."""
    ids = np.full((len(prompts), length), pad_id, np.int32)
    mask = np.zeros(ids.shape, bool)
    image_mask = np.zeros(ids.shape, bool)
    for row, (tokens, slots) in enumerate(prompts):
        if len(tokens) > length:
            raise ValueError(f"a prompt of {len(tokens)} tokens does not fit in {length}")
        ids[row, length - len(tokens):] = tokens
        mask[row, length - len(tokens):] = True
        image_mask[row, length - len(tokens):] = slots
    return ids, mask, image_mask
