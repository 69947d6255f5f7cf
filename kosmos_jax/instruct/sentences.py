"""One instruction sentence from an object's words (verbatim sentence first, else the template)."""

from __future__ import annotations

import re

from kosmos_jax.annotators.base import MissingWordsError, ObjectWords, require
from kosmos_jax.instruct.kinds import TEMPLATES, check_kind


def _as_sentence(text: str) -> str:
    """Single spaces and one final stop (the KOSMOS-E file has a few "details.." endings)."""
    text = re.sub(r"\.{2,}$", ".", " ".join(str(text).split()))
    return text if text.endswith((".", "!", "?")) else text + "."


def object_sentence(words: ObjectWords | None, kind: str, photo_id: str) -> str:
    """The instruction of an object-wise or image-wise kind: name, colour, shape, purpose, strategy."""
    kind = check_kind(kind, ("name", "colour", "shape", "purpose", "strategy"), "an object sentence")
    words = require(words, kind, photo_id)
    verbatim = words.sentences.get(kind)
    if verbatim:
        return _as_sentence(verbatim)
    value = getattr(words, kind)
    if kind == "colour" and " with " in value:
        # "black with yellow details" -> "Grasp the black object with yellow details." (section II)
        head, tail = value.split(" with ", 1)
        return _as_sentence(f"{TEMPLATES[kind].format(colour=head)[:-1]} with {tail}")
    return _as_sentence(TEMPLATES[kind].format(**{kind: value}))


def part_sentence(words: ObjectWords | None, grasp_id: int, photo_id: str) -> str:
    """The part instruction of the photo's grasp number `grasp_id`."""
    words = require(words, "part", photo_id)
    verbatim = words.sentences.get("part") or ()
    if grasp_id < len(verbatim) and verbatim[grasp_id]:
        return _as_sentence(verbatim[grasp_id])
    if grasp_id < len(words.parts) and words.parts[grasp_id]:
        return _as_sentence(TEMPLATES["part"].format(part=words.parts[grasp_id], name=words.name or "object"))
    raise MissingWordsError(f"photo {photo_id!r} has no 'part' words for grasp {grasp_id}")


def angle_sentence(code: int) -> str:
    if not 0 <= int(code) <= 255:
        raise ValueError(f"angle code must be in [0, 255], got {code}")
    return TEMPLATES["angle"].format(code=int(code))


def position_sentence(position: str) -> str:
    return TEMPLATES["position"].format(position=position)


__all__ = ["angle_sentence", "object_sentence", "part_sentence", "position_sentence"]
