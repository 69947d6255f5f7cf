"""Choosing the three distractor photos of a mosaic.

The paper drew them at random, so an instruction such as "Grasp the black object." may fit two
of the four objects. With `unambiguous=True` (the default) a drawn candidate that would make the
instruction ambiguous is rejected and another is drawn; the rejections are counted and reported.

Drawing is sampling without replacement: the candidates are put in a random order (a numpy
Generator) and taken in turn; a rejected candidate is a re-draw. With `unambiguous=False` the
first `count` candidates are taken, the paper's uniform random choice.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from kosmos_jax.annotators.base import ObjectWords, colour_terms, terms

WORD_CLASH_KINDS = ("name", "colour", "shape", "purpose", "strategy")
# Words that do not tell two objects apart; "grasp" and "object" come from whole instruction
# sentences ("Grasp the round object.") used where an annotator has no bare phrase.
STOP_WORDS = frozenset(
    "a an the and or of for with to in on at by its it is that this grasp object".split())


@dataclasses.dataclass(frozen=True)
class DistractorDraw:
    chosen: tuple[int, ...]  # pool indices in the order they fill the free slots
    rejected: tuple[int, ...]  # pool indices drawn and rejected as ambiguous

    @property
    def redraws(self) -> int:
        return len(self.rejected)


def _field_text(words: ObjectWords, kind: str) -> str | None:
    value = getattr(words, kind, None)
    if value is None:
        value = words.sentences.get(kind)
    return None if value is None else str(value)


def content_words(text: str) -> tuple[str, ...]:
    """The words of a phrase that describe the object, in order: lower case, stop words dropped."""
    return terms(text, STOP_WORDS)


def phrases_clash(first: str, second: str, same_head: bool = False) -> bool:
    """True when one phrase's content words are a subset of the other's ("cup" and "coffee cup",
    "round" and "round and flat"), or, with `same_head`, when their last content words agree (the
    head noun of a name: "coffee cup" and "tea cup")."""
    a, b = content_words(first), content_words(second)
    if set(a) <= set(b) or set(b) <= set(a):
        return True
    return same_head and a[-1] == b[-1]


def words_clash(target: ObjectWords | None, candidate: ObjectWords | None, kind: str) -> bool:
    """True when an instruction of `kind` about `target` would also fit `candidate`.

    name, shape, purpose, strategy: `phrases_clash`, names also by their head noun.
    colour: every colour word of the target is also a colour word of the candidate ("black"
    fits a "black and white" object too). A candidate without words for the kind cannot be shown
    to differ, so it clashes.
    """
    if kind not in WORD_CLASH_KINDS:
        raise ValueError(f"no word comparison for kind {kind!r}; expected one of {WORD_CLASH_KINDS}")
    if target is None or candidate is None:
        return True
    target_text, candidate_text = _field_text(target, kind), _field_text(candidate, kind)
    if target_text is None or candidate_text is None:
        return True
    if kind == "colour":
        target_terms = colour_terms(target_text)
        return target_terms <= colour_terms(candidate_text)
    return phrases_clash(target_text, candidate_text, same_head=kind == "name")


def draw_distractors(
    pool_size: int,
    target: int,
    rng: np.random.Generator,
    clash: Callable[[int, int], bool] | None = None,
    count: int = 3,
    unambiguous: bool = True,
    context: str = "",
) -> DistractorDraw:
    """Pick `count` distractor indices from range(pool_size) without the target.

    clash(candidate, slot) says whether the candidate, placed in free slot `slot` (0-based, in the
    order slots are filled), would make the instruction ambiguous. Raises ValueError, naming the
    target and `context`, when the pool cannot supply enough candidates.
    """
    if not 0 <= target < pool_size:
        raise ValueError(f"target index {target} outside a pool of {pool_size}")
    order = rng.permutation(pool_size)
    order = order[order != target]
    if len(order) < count:
        raise ValueError(f"a pool of {pool_size} photos cannot give {count} distractors for photo {target} {context}")
    if not unambiguous or clash is None:
        return DistractorDraw(tuple(int(i) for i in order[:count]), ())
    chosen: list[int] = []
    rejected: list[int] = []
    for candidate in order:
        candidate = int(candidate)
        if clash(candidate, len(chosen)):
            rejected.append(candidate)
            continue
        chosen.append(candidate)
        if len(chosen) == count:
            return DistractorDraw(tuple(chosen), tuple(rejected))
    raise ValueError(
        f"only {len(chosen)} of {pool_size - 1} candidates leave the instruction about photo {target} "
        f"unambiguous {context}; need {count} (pass unambiguous=False to draw at random as the paper did)"
    )
