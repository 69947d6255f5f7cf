"""The KOSMOS-2 prompt layout: one text example as fixed-length token arrays.

    <s> <image> slot_0 .. slot_63 </image> instruction cue value </s> <pad> ...

The slots hold KOSMOS-2's ids 4..67 (`tokens.IMAGE_SLOT_IDS`). With KOSMOS-2's own dictionary
these are ordinary pieces that text can also produce, and with a native model trained before the
slots were reserved they are the tag and patch tokens (so `<image>` and `</image>` ids would occur
twice); a tokenizer trained now reserves them (`Tokenizer.reserves_image_slots`). Either way the
image span is `image_mask` (fixed positions 2..65), never a search for ids.

Each text segment is encoded on its own, so segment boundaries are token boundaries and the loss
mask covers exactly the target's tokens; SentencePiece's leading "▁" of each segment stands for
the space between segments, so decoding the text tokens gives `TextExample.text` back.

Arrays (length `max_length`):
  tokens     int32  model ids, `pad_id` after the end.
  loss_mask  bool   tokens the model is trained to predict (the label at position i is tokens[i];
                    the train step shifts). "target": value tokens and </s>; "instruction": every
                    token after </image>, up to and including </s>.
  image_mask bool   the 64 image slots, whose embeddings the model replaces with image features.
  length     int32  tokens before the padding.
  truncated  bool   the example was cut to fit (only with overflow="truncate").
"""

from __future__ import annotations

import numpy as np

from kosmos_jax.text import tokens as special
from kosmos_jax.text.formatter import FormatConfig, TextExample
from kosmos_jax.text.tokenizer import Tokenizer

PREFIX_LENGTH = 2 + special.IMAGE_SLOTS + 1


class SequenceTooLongError(ValueError):
    """An example needs more tokens than `max_length`."""


def prefix_ids(tokenizer: Tokenizer) -> list[int]:
    return [tokenizer.bos_id, tokenizer.image_start_id, *special.IMAGE_SLOT_IDS, tokenizer.image_end_id]


def slots_mask(length: int) -> np.ndarray:
    """bool [length]: the image slots' fixed positions after <s><image>."""
    mask = np.zeros(length, bool)
    mask[2 : 2 + special.IMAGE_SLOTS] = True
    return mask


def segment_ids(tokenizer: Tokenizer, example: TextExample) -> list[tuple[list[int], bool]]:
    """(ids, is_target) of the instruction, the cue and the value, skipping empty ones."""
    segments = [(example.instruction, False), (example.cue, False), (example.value, True)]
    return [(tokenizer.encode(text), is_target) for text, is_target in segments if text]


def encode_example(example: TextExample, tokenizer: Tokenizer, config: FormatConfig) -> dict[str, np.ndarray]:
    if config.max_length < PREFIX_LENGTH + 2:
        raise ValueError(f"max_length={config.max_length} leaves no room after the {PREFIX_LENGTH}-token image prefix")
    if tokenizer.vocab_size <= max(special.IMAGE_SLOT_IDS):
        raise ValueError(f"vocabulary of {tokenizer.vocab_size} ids has no room for the image slot ids 4..67")
    ids = prefix_ids(tokenizer)
    in_loss = [False] * len(ids)
    whole_text = config.loss_on == "instruction"
    for segment, is_target in segment_ids(tokenizer, example):
        ids += segment
        in_loss += [is_target or whole_text] * len(segment)
    ids.append(tokenizer.eos_id)
    in_loss.append(True)
    truncated = len(ids) > config.max_length
    if truncated:
        if config.overflow == "error":
            raise SequenceTooLongError(
                f"example of photos {example.photo_ids} ({example.kind}, {example.part}) needs {len(ids)} tokens, "
                f"more than max_length={config.max_length}: {example.text!r}"
            )
        ids, in_loss = ids[: config.max_length], in_loss[: config.max_length]
    length = len(ids)
    tokens = np.full(config.max_length, tokenizer.pad_id, np.int32)
    tokens[:length] = ids
    loss_mask = np.zeros(config.max_length, bool)
    loss_mask[:length] = in_loss
    image_mask = slots_mask(config.max_length)
    return {
        "tokens": tokens,
        "loss_mask": loss_mask,
        "image_mask": image_mask,
        "length": np.int32(length),
        "truncated": np.bool_(truncated),
    }


def text_span(encoded: dict[str, np.ndarray]) -> slice:
    """The positions of the text tokens: after </image>, before </s>."""
    return slice(PREFIX_LENGTH, int(encoded["length"]) - 1)
