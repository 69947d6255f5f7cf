"""ObjectWords: what an annotator knows about the object of one photo.

Every annotator (the KOSMOS-E file, the synthetic scenes' metadata, rules over pixels, a VLM)
returns one of these; the instruction builders consume nothing else.

Fields hold the words that fill the templates of `kosmos_jax.instruct.kinds`:
  name "remote control", colour "black" or "green, yellow, and silver", shape "rectangular",
  purpose "controlling electronic devices wirelessly", strategy the whole strategy text,
  parts one part phrase per grasp ("middle section"), aligned with the photo's grasps.
`sentences` holds whole instruction sentences where the annotator has them (kind -> sentence,
and "part" -> a tuple with one sentence per grasp); they are used verbatim instead of a template.
`unknown` names the kinds an annotator could not derive, each with the reason (kind -> "photo
pcd0104 (.../pcd0104r.png): no pixel differs from the background ..."): the samples of those kinds
are left out for the photo (and counted), where words that are merely missing are an error.
"""

from __future__ import annotations

import dataclasses
import re
from typing import Collection, Mapping

WORD_KINDS = ("name", "colour", "shape", "purpose", "strategy")


class MissingWordsError(ValueError):
    """A photo has no words for the requested instruction kind."""


@dataclasses.dataclass(frozen=True)
class ObjectWords:
    name: str | None = None
    colour: str | None = None
    shape: str | None = None
    purpose: str | None = None
    strategy: str | None = None
    parts: tuple[str | None, ...] = ()
    sentences: Mapping[str, object] = dataclasses.field(default_factory=dict)
    unknown: Mapping[str, str] = dataclasses.field(default_factory=dict)

    def has(self, kind: str) -> bool:
        """Whether there are words for `kind`; an empty or blank phrase is no words."""
        if kind == "part":
            return any(_present(p) for p in self.parts) or any(_present(s) for s in self.sentences.get("part") or ())
        return _present(getattr(self, kind, None)) or _present(self.sentences.get(kind))


def _present(text) -> bool:
    return text is not None and bool(str(text).strip())


def require(words: ObjectWords | None, kind: str, photo_id: str) -> ObjectWords:
    """`words` if it can make an instruction of `kind`, else an error naming the photo and kind."""
    if words is None:
        raise MissingWordsError(f"photo {photo_id!r} has no annotation at all; cannot make a {kind!r} instruction")
    if kind in words.unknown:
        raise MissingWordsError(f"photo {photo_id!r} has no {kind!r} words ({words.unknown[kind]}); "
                                f"cannot make a {kind!r} instruction")
    if not words.has(kind):
        raise MissingWordsError(f"photo {photo_id!r} has no {kind!r} words; cannot make a {kind!r} instruction")
    return words


def normalise_text(text: str) -> str:
    """Lower case, single spaces, no trailing full stop: the form compared for ambiguity."""
    return re.sub(r"\s+", " ", str(text)).strip().rstrip(".").strip().lower()


def terms(text: str, drop: Collection[str] = ()) -> tuple[str, ...]:
    """The words of `text` in order, normalised ("navy-blue" and "driver's" are one word each),
    without those in `drop`."""
    return tuple(w for w in re.findall(r"[a-z0-9]+(?:['-][a-z0-9]+)*", normalise_text(text)) if w not in drop)


_COLOUR_FILLER = {"and", "with", "details", "detail", "accents", "accent", "a", "an", "the", "of", "some", "object"}


_COLOUR_SPELLINGS = {"grey": "gray", "colour": "color"}


def colour_terms(colour: str) -> frozenset[str]:
    """The colour words of a colour phrase: "green, yellow, and silver" -> {green, yellow, silver}
    ("grey" and "gray" are one word)."""
    return frozenset(_COLOUR_SPELLINGS.get(t, t) for t in terms(colour, _COLOUR_FILLER))
