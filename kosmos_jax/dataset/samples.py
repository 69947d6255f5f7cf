"""Views of one split -> INSTRUCT-GRASP samples, deterministically, so a build can make two passes.

Kinds are named "non", the SINGLE kinds ("angle", "part", "name", ...) and "multi-<kind>" for
mosaics ("multi-colour"). Every view gives the samples of each single kind and one mosaic per
multi kind with itself as the target; the distractors come from the same split's views only, so
a mosaic never mixes photos of two splits. Randomness is a numpy Generator seeded by
(seed, split, view, kind), independent of the pass and of the other kinds.
"""

from __future__ import annotations

import dataclasses
from typing import Iterable, Iterator, Sequence

import numpy as np

from kosmos_jax.annotators.base import MissingWordsError
from kosmos_jax.instruct.kinds import ALL_KINDS, MULTI_KINDS, SINGLE_KINDS, check_kind
from kosmos_jax.instruct.mosaic import build_mosaic
from kosmos_jax.instruct.sample import Sample, View
from kosmos_jax.instruct.single import single_samples

MULTI_PREFIX = "multi-"
ALL_BUILD_KINDS = ALL_KINDS + tuple(MULTI_PREFIX + k for k in MULTI_KINDS)
SPLIT_TAGS = {"train": 0, "test": 1, "validation": 2}


def parse_kinds(names: Iterable[str]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """("non", "colour", "multi-name", ...) -> (single kinds, multi kinds); "single", "multi" and
    "all" expand. An unknown kind is a ValueError naming it."""
    single: list[str] = []
    multi: list[str] = []
    for name in names:
        name = str(name).strip().lower()
        if name == "all":
            single += ALL_KINDS
            multi += MULTI_KINDS
        elif name == "single":
            single += SINGLE_KINDS
        elif name == "multi":
            multi += MULTI_KINDS
        elif name.startswith(MULTI_PREFIX):
            multi.append(check_kind(name[len(MULTI_PREFIX):], MULTI_KINDS, "a multi-object mosaic"))
        else:
            single.append(check_kind(name, ALL_KINDS, "a single-object scene (or multi-<kind> for a mosaic)"))
    dedupe = lambda kinds: tuple(dict.fromkeys(kinds))
    if not single and not multi:
        raise ValueError("no instruction kinds selected")
    return dedupe(single), dedupe(multi)


def kind_label(sample: Sample) -> str:
    return MULTI_PREFIX + sample.kind if sample.scene == "multi" else sample.kind


@dataclasses.dataclass
class MosaicCounts:
    built: int = 0
    redraws: int = 0
    skipped: int = 0
    skip_reasons: list = dataclasses.field(default_factory=list)


def _count(counts: dict[str, int] | None, label: str) -> None:
    if counts is not None:
        counts[label] = counts.get(label, 0) + 1


def split_samples(
    views: Sequence[View],
    single_kinds: Sequence[str],
    multi_kinds: Sequence[str],
    seed: int,
    split: str,
    mosaics: MosaicCounts | None = None,
    unambiguous: bool = True,
    position_mode: str = "quadrant",
    skipped: dict[str, int] | None = None,
) -> Iterator[tuple[int, Sample]]:
    """(view index, sample) of every sample of the split, in a fixed order.

    A mosaic the split cannot make (too few views whose words differ from the target's) is
    skipped and counted in `mosaics`; missing words are an error naming the photo, except the
    kinds its words mark unknown (`ObjectWords.unknown`): those samples (single and mosaic with
    that photo as target) are left out and counted in `skipped` by kind label. Such a photo is
    never a distractor for those kinds (without words it cannot be shown to differ).
    """
    tag = SPLIT_TAGS[split]
    for index, view in enumerate(views):
        without = view.words.unknown if view.words is not None else {}
        for kind in single_kinds:
            if kind in without:
                _count(skipped, kind)
                continue
            for sample in single_samples(view, kind):
                yield index, sample
        for number, kind in enumerate(multi_kinds):
            if kind in without:
                _count(skipped, MULTI_PREFIX + kind)
                continue
            rng = np.random.default_rng([seed, tag, index, number])
            try:
                sample = build_mosaic(views, index, kind, rng, unambiguous, position_mode)
            except MissingWordsError:
                raise
            except ValueError as error:  # not enough distractors in this split
                if mosaics is not None:
                    mosaics.skipped += 1
                    if len(mosaics.skip_reasons) < 3:
                        mosaics.skip_reasons.append(str(error))
                continue
            if mosaics is not None:
                mosaics.built += 1
                mosaics.redraws += sample.redraws
            yield index, sample
