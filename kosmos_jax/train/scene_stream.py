"""Training batches made on the fly from synthetic scenes that never repeat (config.data.stream).

Chunk k holds `photos` fresh scenes of seed `seed + k`, made in a temporary folder and deleted
once read, then the dataset build's own stages: augmented views, samples of every kind the build
asks for (mosaics drawn within the chunk), text, tokens with the run's fixed tokenizer. The
chunk's examples (at most `examples` of them, drawn at random with (seed, k), when it is set: more
scenes a chunk with fewer examples of each) are shuffled with (seed, k) and cut into global batches; process p takes rows
p, p + P, ... of each. Nothing is stored: the position is (chunk, batch), and `set_state`
remakes that chunk, so a resumed run sees the same batches as one never stopped. The next chunk
is made in a background thread while the current one is read.

An example's `example_index` is chunk * CHUNK_STRIDE + its place in the chunk: unique across the
stream, so dropout masks (drawn from it) never repeat either. Its `category` and `colour` are the labels
of its target object's category and main colour (`tower_labels`), which only scenes made here can give.
With targets="best" each scene keeps only its expected best grasp (sources/synthetic/best_grasps.py) before its
views are made: targets that do not move from draw to draw, which only scenes made here can give too.
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import pathlib
import sys
import tempfile

import numpy as np

from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.sources.synthetic.best_grasps import keep_best_grasps
from kosmos_jax.dataset import build as build_lib
from kosmos_jax.dataset import samples as sample_stage
from kosmos_jax.dataset.inputs import object_words, read_photos, word_source
from kosmos_jax.dataset.pipeline import to_arrays
from kosmos_jax.dataset.tfds_builders import example_record
from kosmos_jax.dataset.views import augment_config, make_views
from kosmos_jax.text import layout
from kosmos_jax.train.tower_labels import label_of

CHUNK_STRIDE = 10**7  # more examples than any chunk makes
TARGETS = ("", "best")  # "": the annotation's own draw


def photo_labels(metadata: dict) -> dict[str, dict[str, int]]:
    """{photo id: {label kind: its object's label}} from a synthetic folder's metadata (its parsed
    synthetic_meta.json); an object's colour is its main one, the first it lists."""
    return {photo_id: {"category": label_of("category", meta["category"]),
                       "colour": label_of("colour", meta["colour"][0])}
            for photo_id, meta in metadata["photos"].items()}


@dataclasses.dataclass(frozen=True)
class Chunk:
    arrays: dict  # name -> [examples, ...] stacked, in shuffled order
    labels: list  # "photo ids (kind)" of each example, same order


def scene_examples(build_config: build_lib.BuildConfig, photos: int, scene_seed: int, targets: str = ""):
    """(the (sample, text example) pairs of `photos` fresh scenes of `scene_seed` as `build_config`'s training
    split makes them, in its order; {photo id: {label kind: label}}). The scenes' files are gone on return."""
    config = dataclasses.replace(build_config, seed=scene_seed)
    single, multi = sample_stage.parse_kinds(config.kinds or ("all",))
    with tempfile.TemporaryDirectory(prefix="kosmos_jax-stream-") as folder:
        source = pathlib.Path(folder) / "scenes"
        scenes.write_dataset(source, photos=photos, seed=scene_seed)
        if targets == "best":
            keep_best_grasps(source)
        photo_list, image_files = read_photos(source)
        words_from = word_source(source, None)  # the scenes' metadata, read once for the words and the labels
        words = object_words(words_from, photo_list, image_files)
        object_labels = photo_labels(words_from.document)
    index = {p.id: i for i, p in enumerate(photo_list)}
    made, _ = make_views(photo_list, words, augment_config(config.augmentations, config.recipe,
                                                           config.train_crop or "gt_centroid"),
                         scene_seed, index, False, config.batch_size)
    views = [made[key] for key in sorted(made)]
    return build_lib._examples(config, views, single, multi, "train"), object_labels


def make_chunk(build_config: build_lib.BuildConfig, tokenizer, photos: int, scene_seed: int, number: int,
               examples: int = 0, targets: str = "") -> Chunk:
    """Chunk `number` of the stream: `photos` scenes of `scene_seed`, as training examples of `build_config`;
    `examples` > 0 keeps that many of them (or all, if fewer fit max_length), drawn at random."""
    format_config = build_config.format_config()
    made_examples, object_labels = scene_examples(build_config, photos, scene_seed, targets)
    if examples:  # tokens made in a random order until `examples` fit: the others cost nothing
        made_examples = list(made_examples)
        made_examples = [made_examples[i] for i in np.random.default_rng([scene_seed, number, examples])
                         .permutation(len(made_examples))]
    rows, labels, too_long = [], [], 0
    for sample, example in made_examples:
        if examples and len(rows) == examples:
            break
        try:
            encoded = layout.encode_example(example, tokenizer, format_config)
        except layout.SequenceTooLongError:
            too_long += 1
            continue
        record = example_record(encoded, example)
        arrays = to_arrays(record, max_answers=64, example_index=number * CHUNK_STRIDE + len(rows))
        for kind, label in object_labels[example.photo_ids[example.target]].items():
            arrays[kind] = np.int32(label)
        rows.append(arrays)
        labels.append(f"{'+'.join(example.photo_ids)} ({sample_stage.kind_label(sample)})")
    order = np.random.default_rng([scene_seed, number]).permutation(len(rows))
    arrays = {name: np.stack([rows[i][name] for i in order]) for name in rows[0]}
    if too_long:
        print(f"scene stream chunk {number}: {too_long} of {too_long + len(rows)} examples left out, longer than "
              f"max_length={format_config.max_length} with this tokenizer", file=sys.stderr, flush=True)
    return Chunk(arrays, [labels[i] for i in order])


class SceneStream:
    """Endless host batches of this process's rows; get_state() / set_state() for checkpoints."""

    def __init__(self, build_config: build_lib.BuildConfig, tokenizer, *, photos: int, seed: int,
                 global_batch: int, process_index: int = 0, process_count: int = 1, examples: int = 0,
                 targets: str = ""):
        if global_batch % process_count:
            raise ValueError(f"train.batch_size={global_batch} is not divisible by the {process_count} processes")
        if examples < 0:
            raise ValueError(f"config.data.stream.examples={examples} must be >= 0 (0: every example a chunk makes)")
        if targets not in TARGETS:
            raise ValueError(f"config.data.stream.targets={targets!r}: expected one of {TARGETS}")
        self._make = lambda number: make_chunk(build_config, tokenizer, photos, seed + number, number, examples, targets)
        self.global_batch, self.process_index, self.process_count = global_batch, process_index, process_count
        self._pool = concurrent.futures.ThreadPoolExecutor(max_workers=1, thread_name_prefix="scene-stream")
        self._chunk_number, self._batch = 0, 0
        self._chunk: Chunk | None = None
        self._next: concurrent.futures.Future | None = None
        self._next_number = -1
        self.last_labels: list[str] = []

    def chunk(self, number: int) -> Chunk:
        """Chunk `number` of this stream, made now (what training reads from it, for inspection)."""
        return self._make(number)

    def _batches_in(self, chunk: Chunk) -> int:
        return len(chunk.labels) // self.global_batch

    def _load(self, number: int) -> None:
        if self._next is not None and self._next_number == number:
            self._chunk = self._next.result()
        else:
            self._chunk = self._make(number)
        if self._batches_in(self._chunk) == 0:
            raise ValueError(f"chunk {number} of the scene stream made {len(self._chunk.labels)} examples, fewer than "
                             f"one batch of {self.global_batch}: raise config.data.stream.photos")
        self._chunk_number = number
        self._next_number = number + 1
        self._next = self._pool.submit(self._make, number + 1)

    def __iter__(self):
        return self

    def __next__(self) -> dict:
        if self._chunk is None:
            self._load(self._chunk_number)
        if self._batch >= self._batches_in(self._chunk):
            self._batch = 0
            self._load(self._chunk_number + 1)
        start = self._batch * self.global_batch
        rows = slice(start + self.process_index, start + self.global_batch, self.process_count)
        self._batch += 1
        self.last_labels = self._chunk.labels[rows]
        return {name: value[rows] for name, value in self._chunk.arrays.items()}

    def get_state(self) -> dict:
        return {"chunk": self._chunk_number, "batch": self._batch}

    def set_state(self, state: dict) -> None:
        self._chunk_number, self._batch = int(state["chunk"]), int(state["batch"])
        self._chunk = None

    def describe(self, host) -> list[str]:
        """'photo ids (kind)' of the rows of the batch last returned."""
        return list(self.last_labels)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)
