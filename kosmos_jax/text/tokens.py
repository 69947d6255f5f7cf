"""The special tokens of KOSMOS-2 and the dedicated value tokens of the grasp text.

KOSMOS-2's fairseq dictionary (DESIGN.md section 4) holds `<s>`=0, `<pad>`=1, `</s>`=2, `<unk>`=3,
the SentencePiece pieces shifted by one, `<mask>`, then the 11 tag tokens below in this order,
then `<patch_index_0000>`..`<patch_index_1023>`. With its 64000-piece model that puts `<image>` at
64003, `</image>` at 64004, `<grounding>` at 64012 and the patch tokens at 64013..65036.

Value tokens ("x_12", "a_77") make every number of a grasp one token. Their ranges cover every
value `kosmos_jax.grasp_text.parse_grasp` accepts, so a target that parses has no value outside
the vocabulary.
"""

from __future__ import annotations

from kosmos_jax import geometry
from kosmos_jax.grasp_text import PATCH_GRID, check_representation

BOS, PAD, EOS, UNK = "<s>", "<pad>", "</s>", "<unk>"
IMAGE_START, IMAGE_END = "<image>", "</image>"
TAG_TOKENS = (
    "</doc>",
    IMAGE_START,
    IMAGE_END,
    "</chunk>",
    "</line>",
    "<phrase>",
    "</phrase>",
    "<object>",
    "</object>",
    "</delimiter_of_multi_objects/>",
    "<grounding>",
)
PATCH_TOKENS = tuple(f"<patch_index_{i:04d}>" for i in range(PATCH_GRID * PATCH_GRID))
SPECIAL_SYMBOLS = TAG_TOKENS + PATCH_TOKENS

IMAGE_SLOTS = 64
# KOSMOS-2 fills its 64 image slots with the ids 4..67; the model overwrites their embeddings with
# the image features, so the ids only have to exist in the vocabulary. In KOSMOS-2's own
# dictionary they are ordinary pieces (text may use them too; the slots are known by position,
# `image_mask`, never by id). A tokenizer trained here reserves them: 4..67 are the control
# symbols below, which no text encodes to and which decode to nothing, so the tags and patch
# tokens (from 68 on) never share an id with a slot.
FIRST_SLOT_ID = 4
IMAGE_SLOT_IDS = tuple(range(FIRST_SLOT_ID, FIRST_SLOT_ID + IMAGE_SLOTS))
IMAGE_SLOT_TOKENS = tuple(f"<image_slot_{i:02d}>" for i in range(IMAGE_SLOTS))

NUMBER_MODES = ("digits", "values")


def value_tokens(representation: str = "xya", image_size: int = 224) -> tuple[str, ...]:
    """Every value token the target text of `representation` can need (angle code on)."""
    check_representation(representation)
    if representation == "tlbra":
        # the axis-aligned box of a rectangle may stick out of the image; the parser accepts
        # corners in [-image_size, 2 * image_size]
        coords = range(-image_size, 2 * image_size + 1)
    else:
        coords = range(image_size)
    tokens = [f"x_{v}" for v in coords] + [f"y_{v}" for v in coords]
    if representation == "xywha":
        sizes = range(1, 2 * image_size + 1)
        tokens += [f"w_{v}" for v in sizes] + [f"h_{v}" for v in sizes]
    tokens += [f"a_{k}" for k in range(geometry.ANGLE_BINS)]
    return tuple(tokens)


def check_number_mode(numbers: str) -> str:
    if numbers not in NUMBER_MODES:
        raise ValueError(f"unknown number mode {numbers!r}; expected one of {NUMBER_MODES}")
    return numbers
