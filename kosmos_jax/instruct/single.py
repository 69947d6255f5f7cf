"""INSTRUCT-GRASP-NON and -SINGLE samples from one augmented view.

Object-wise and image-wise kinds (name, colour, shape, purpose, strategy, position) give one
sample whose answers are all the view's grasps. Grasp-wise kinds (angle, part) give one sample
per grasp, as the paper does; its answers are the grasps that share the same sentence (the same
angle code, the same part sentence), the grasp it was made from first.
"""

from __future__ import annotations

import numpy as np

from kosmos_jax import geometry
from kosmos_jax.annotators.base import MissingWordsError, normalise_text, require
from kosmos_jax.annotators import position as position_words
from kosmos_jax.instruct.kinds import ALL_KINDS, ANSWERS, NON, check_kind
from kosmos_jax.instruct.sample import Sample, View
from kosmos_jax.instruct.sentences import angle_sentence, object_sentence, part_sentence, position_sentence


def _checked_grasps(view: View) -> np.ndarray:
    grasps = np.asarray(view.grasps, np.float64)
    if grasps.ndim != 2 or grasps.shape[1] != 5:
        raise ValueError(f"photo {view.photo_id!r}: grasps must be [N, 5], got shape {grasps.shape}")
    if grasps.shape[0] == 0:
        raise ValueError(f"photo {view.photo_id!r} has no grasps; cannot make a sample")
    return grasps


def _sample(view: View, kind: str, instruction: str, grasps: np.ndarray) -> Sample:
    return Sample(
        kind=kind,
        scene=NON if kind == NON else "single",
        instruction=instruction,
        answer=ANSWERS[kind],
        image=view.image,
        grasps=grasps,
        photo_ids=(view.photo_id,),
        object_ids=(view.object_id,),
    )


def _per_grasp(view: View, kind: str, sentences: list[str], grasps: np.ndarray) -> list[Sample]:
    keys = [normalise_text(s) for s in sentences]
    samples = []
    for i, sentence in enumerate(sentences):
        same = [j for j in range(len(sentences)) if keys[j] == keys[i] and j != i]
        samples.append(_sample(view, kind, sentence, grasps[[i] + same]))
    return samples


def _part_samples(view: View, grasps: np.ndarray) -> list[Sample]:
    """Part samples of the grasps that have part words; a grasp without them is skipped (the
    KOSMOS-E file has a few GPT-4V refusals), but a view with none at all is an error."""
    require(view.words, "part", view.photo_id)
    kept, sentences = [], []
    for row, grasp_id in enumerate(view.ids()):
        try:
            sentences.append(part_sentence(view.words, int(grasp_id), view.photo_id))
        except MissingWordsError:
            continue
        kept.append(row)
    if not kept:
        raise MissingWordsError(f"photo {view.photo_id!r} has no 'part' words for any of its {len(grasps)} grasps")
    return _per_grasp(view, "part", sentences, grasps[kept])


def single_samples(view: View, kind: str) -> list[Sample]:
    """The samples of one kind ("non" or a SINGLE kind) for one view."""
    kind = check_kind(kind, ALL_KINDS, "a single-object scene")
    grasps = _checked_grasps(view)
    if kind == NON:
        return [_sample(view, kind, "", grasps)]
    if kind == "angle":
        codes = np.asarray(geometry.encode_angle(grasps[:, 4]))
        return _per_grasp(view, kind, [angle_sentence(int(c)) for c in codes], grasps)
    if kind == "part":
        return _part_samples(view, grasps)
    if kind == "position":
        height, width = np.asarray(view.image).shape[:2]
        return [_sample(view, kind, position_sentence(position_words.position_word(grasps, width, height)), grasps)]
    return [_sample(view, kind, object_sentence(view.words, kind, view.photo_id), grasps)]
