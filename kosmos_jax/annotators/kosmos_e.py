"""Words from the KOSMOS-E authors' annotations (`instructions-original.json`).

One entry per photo: obj_name, instruction_name / _color / _shape / _purpose / _strategy (whole
sentences) and instruction_part ({"0": sentence, ...}, one per non-NaN rectangle in file order).
The reader kosmos_jax/sources/kosmos_e_annotations.py attaches an entry to `Photo.annotations`
(the raw entry under "instructions", the object name under "name"); this module reads either that
or a raw entry.

The sentences are kept verbatim for the instructions, and the slot words are cut out of them for
the ambiguity checks of the mosaics. The file holds GPT-4V answers that are not instructions
("I'm sorry, I cannot assist with these requests.", "The object in this image is swimming
goggles."): a sentence that does not start with "Grasp" is dropped (the name then comes from the
template; a part becomes missing for that grasp). `junk_sentences` lists them.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Any, Mapping

from kosmos_jax.annotators.base import ObjectWords

RAW_KEYS = {
    "name": "instruction_name",
    "colour": "instruction_color",
    "shape": "instruction_shape",
    "purpose": "instruction_purpose",
    "strategy": "instruction_strategy",
}

_BODY = re.compile(r"^gr(?:asp|sap) the (.+?)\.*$", re.IGNORECASE)  # "Grsap" is in the file
_PURPOSE = re.compile(r"^grasp the (?:object|obejct|item) (?:that is )?(?:used )?for (.+?)\.*$", re.IGNORECASE)
_PART = re.compile(r"^grasp the (.+?) of (?:the |an? )?.+?\.*$", re.IGNORECASE)


def _clean(text: Any) -> str | None:
    if text is None:
        return None
    text = " ".join(str(text).split())
    return text or None


def is_instruction(sentence: str | None, kind: str) -> bool:
    """A usable annotation sentence: strategies are free text; other kinds must start with "Grasp"."""
    if not sentence:
        return False
    return kind == "strategy" or sentence.lower().startswith(("grasp", "grsap"))


def _body(sentence: str) -> str | None:
    match = _BODY.match(sentence)
    return match.group(1) if match else None


def slot_words(kind: str, sentence: str) -> str | None:
    """The words of a sentence that fill the kind's template slot."""
    if kind == "strategy":
        return sentence
    if kind == "purpose":
        match = _PURPOSE.match(sentence)
        return match.group(1) if match else _body(sentence)
    body = _body(sentence)
    if body is None:
        return None
    if kind == "colour":
        return " ".join(re.sub(r"\bobject\b", " ", body).split()) or None
    if kind == "shape":
        return body.split(" object")[0] if " object" in body else body
    return body


def part_words(sentence: str) -> str | None:
    match = _PART.match(sentence)
    return match.group(1) if match else None


def _part_sentences(raw: Any) -> list[str | None]:
    if raw is None:
        return []
    if isinstance(raw, Mapping):
        keys = sorted(raw, key=lambda k: int(k))
        if [int(k) for k in keys] != list(range(len(keys))):
            raise ValueError(f"instruction_part keys must be 0..{len(keys) - 1}, got {keys}")
        raw = [raw[k] for k in keys]
    return [_clean(s) for s in raw]


def words_from_entry(entry: Mapping[str, Any]) -> ObjectWords:
    """ObjectWords from one KOSMOS-E entry: the raw JSON entry, or the `Photo.annotations` of
    kosmos_jax.sources.kosmos_e_annotations (which keeps the raw entry under "instructions")."""
    raw = entry.get("instructions")
    if isinstance(raw, Mapping):
        return dataclasses.replace(words_from_entry(raw), name=_clean(entry.get("name")) or _clean(raw.get("obj_name")))
    sentences: dict[str, Any] = {}
    fields: dict[str, str | None] = {}
    for kind, raw_key in RAW_KEYS.items():
        sentence = _clean(entry.get(raw_key))
        if is_instruction(sentence, kind):
            sentences[kind] = sentence
        fields[kind] = slot_words(kind, sentences[kind]) if kind in sentences else None
    name = _clean(entry.get("obj_name")) or fields["name"]
    part_sentences = [s if is_instruction(s, "part") else None for s in _part_sentences(entry.get("instruction_part"))]
    if any(part_sentences):
        sentences["part"] = tuple(part_sentences)
    return ObjectWords(
        name=name,
        colour=fields["colour"],
        shape=fields["shape"],
        purpose=fields["purpose"],
        strategy=fields["strategy"],
        parts=tuple(part_words(s) if s else None for s in part_sentences),
        sentences=sentences,
    )


def words_from_photo(photo) -> ObjectWords:
    """ObjectWords of a `Photo` whose `annotations` hold a KOSMOS-E entry."""
    if not photo.annotations:
        raise ValueError(f"photo {photo.id!r} has no KOSMOS-E annotations attached")
    words = words_from_entry(photo.annotations)
    n_grasps = len(photo.grasps)
    n_parts = max(len(words.parts), len(words.sentences.get("part", ())))
    if n_parts and n_parts != n_grasps:
        raise ValueError(
            f"photo {photo.id!r}: the annotation has {n_parts} part instructions but the photo has {n_grasps} grasps"
        )
    return words


def junk_sentences(entry: Mapping[str, Any]) -> list[tuple[str, str]]:
    """(kind, sentence) of every annotation sentence that is not an instruction."""
    entry = entry.get("instructions", entry)
    junk = [(k, s) for k, key in RAW_KEYS.items() if (s := _clean(entry.get(key))) and not is_instruction(s, k)]
    junk += [("part", s) for s in _part_sentences(entry.get("instruction_part")) if s and not is_instruction(s, "part")]
    return junk
