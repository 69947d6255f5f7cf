"""Every photo of a Cornell-format folder as evaluation examples, made as the build makes them.

Honest test views (dataset.views.evaluation_views: the crop at the photo's centre, never at the
labels), samples of the asked kinds (dataset.samples), the run's text format and tokenizer
(formatter, layout): records shaped like a stored split's (tfds_builders.example_record), each
holding its image. A view whose grasps all left the crop has nothing to score against: it is
left out and counted.
"""

from __future__ import annotations

import dataclasses
import pathlib
from collections.abc import Sequence

import numpy as np

from kosmos_jax.dataset import samples
from kosmos_jax.dataset.inputs import object_words, read_photos, word_source
from kosmos_jax.dataset.tfds_builders import example_record
from kosmos_jax.dataset.views import evaluation_views
from kosmos_jax.instruct.kinds import NON
from kosmos_jax.instruct.sample import View
from kosmos_jax.text import layout
from kosmos_jax.text.formatter import FormatConfig, format_sample
from kosmos_jax.text.tokenizer import Tokenizer


LONGEST_EXAMPLE = 1024  # tokens


@dataclasses.dataclass(frozen=True)
class CornellExamples:
    records: list[dict]
    photos: int
    views_without_grasps: int


def honest_views(folder: pathlib.Path, kinds: Sequence[str]) -> tuple[list[View], int, int]:
    """(instruction-stage views of every photo that keeps a grasp, photos read, views left out)."""
    photos, image_files = read_photos(folder)
    single, multi = samples.parse_kinds(kinds)
    needs_words = bool(multi) or any(kind != NON for kind in single)
    words = object_words(word_source(folder, None), photos, image_files) if needs_words else {}
    object_of = {photo.id: photo.object_id for photo in photos}
    made = evaluation_views(photos, "honest")
    views = [View(photo_id, made.images[row], made.grasps[row][made.mask[row]], words.get(photo_id),
                  object_of[photo_id], np.flatnonzero(made.mask[row]))
             for row, photo_id in enumerate(made.photo_id) if made.mask[row].any()]
    return views, len(photos), len(made.photo_id) - len(views)


def cornell_examples(folder, tokenizer: Tokenizer, config: FormatConfig, kinds: Sequence[str] = (NON,),
                     seed: int = 0) -> CornellExamples:
    """The records of every photo of `folder` for instructions of `kinds` (the build's names: "non",
    "colour", "multi-name", "all", ...), one target grasp per instruction."""
    views, photos, left_out = honest_views(pathlib.Path(folder), kinds)
    single, multi = samples.parse_kinds(kinds)
    # one target per instruction (the answers are all its grasps anyway); sentences longer than the
    # run's training length are kept whole: nothing is trained on them
    config = dataclasses.replace(config, target_grasp="first", max_length=max(config.max_length, LONGEST_EXAMPLE))
    records = [example_record(layout.encode_example(example, tokenizer, config), example)
               for _, sample in samples.split_samples(views, single, multi, seed, "test")
               for example in format_sample(sample, config)]
    if not records:
        raise ValueError(f"{folder}: no photo keeps a grasp inside its test view; nothing to evaluate")
    return CornellExamples(records, photos, left_out)
