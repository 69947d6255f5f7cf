"""A grain input pipeline over a written split: shuffle, shard by process, batch, resume exactly.

The split is a `StoredSplit` (`tfds_builders.open_splits`): example records that hold an
`image_index`, and the split's image table. The pipeline shuffles and shards the examples, and
its map step joins each one's image back (decoding its PNG), so the image is read once per
example drawn, as before, while it is stored once per view or mosaic.

Order of operations: a seeded global shuffle of the whole split (every process draws the same
permutation), then process `process_index` takes every `process_count`-th example of it, so the
processes see disjoint parts of each epoch; then records become fixed-shape arrays and are
batched. Shards are even: the last `len % process_count` examples of each epoch's permutation are
left out (other ones each epoch), so every process makes the same number of batches and no host
waits in a collective for one that has run out (`even_shards=False` keeps them, for a
single-process evaluation that must see every example). Epochs repeat with a fresh permutation each (`reseed_each_epoch`). The iterator's
`get_state()` is a small dict that `set_state()` restores exactly, for saving beside a checkpoint.

A batch holds the numeric features only (strings stay in the files): image uint8 [B, S, S, 3],
tokens int32 [B, L], loss_mask / image_mask bool [B, L], length int32 [B], grasp float32 [B, 5],
grasp_mask bool [B, 5], answers float32 [B, A, 5] padded to `max_answers` with answers_mask
bool [B, A], and example_index int64 [B]: each example's position in the split, to name it (its
photo ids and kind, in `split.examples`) when something goes wrong.
"""

from __future__ import annotations

from typing import Any, Mapping

import grain
import numpy as np

# tfds hands scalars back as Python ints (int64 once stacked), hence the explicit dtypes
NUMERIC_FEATURES = {"image": np.uint8, "tokens": np.int32, "loss_mask": np.bool_, "image_mask": np.bool_,
                    "length": np.int32, "grasp": np.float32, "grasp_mask": np.bool_}


def to_arrays(record: Mapping[str, Any], max_answers: int, example_index: int = -1) -> dict[str, np.ndarray]:
    """One stored record -> fixed-shape numpy arrays (answers padded to `max_answers`)."""
    arrays = {name: np.asarray(record[name], dtype) for name, dtype in NUMERIC_FEATURES.items()}
    arrays["example_index"] = np.int64(example_index)
    answers = np.asarray(record["answers"], np.float32).reshape(-1, 5)
    if answers.shape[0] > max_answers:
        raise ValueError(f"record with {answers.shape[0]} answer grasps exceeds max_answers={max_answers}")
    padded = np.zeros((max_answers, 5), np.float32)
    padded[: answers.shape[0]] = answers
    mask = np.zeros(max_answers, bool)
    mask[: answers.shape[0]] = True
    arrays["answers"], arrays["answers_mask"] = padded, mask
    return arrays


def make_dataset(
    split,
    batch_size: int,
    *,
    seed: int = 0,
    shuffle: bool = True,
    process_index: int = 0,
    process_count: int = 1,
    num_epochs: int | None = 1,
    drop_remainder: bool = True,
    even_shards: bool = True,
    max_answers: int = 64,
    read_options: grain.ReadOptions | None = None,
    order: np.ndarray | None = None,
) -> grain.IterDataset:
    """The batched dataset of one split (a `StoredSplit`: `.examples` and `.images`); `iter()` it,
    and use get_state / set_state to resume (the state is the examples' position only: the join is
    a pure function of the example). `order`: the example indices an epoch draws from, repeats
    allowed (None: each example once)."""
    if batch_size < 1:
        raise ValueError(f"batch_size must be positive, got {batch_size}")
    if not 0 <= process_index < process_count:
        raise ValueError(f"process_index {process_index} outside 0..{process_count - 1}")
    drawn = len(split.examples) if order is None else len(order)
    if drawn < process_count:
        raise ValueError(f"a split of {drawn} examples cannot be shared by {process_count} processes")
    images, examples = split.images, split.examples
    # a source of example indices: None draws each once, in the order (and with the states) a source of the
    # examples themselves gave
    indices = np.arange(len(examples)) if order is None else np.asarray(order, np.int64)
    dataset = grain.MapDataset.source(indices).map(lambda index: (int(index), examples[int(index)]))
    if shuffle:
        dataset = dataset.shuffle(seed=seed)
    if even_shards:
        dataset = dataset[: len(dataset) - len(dataset) % process_count]
    dataset = dataset[process_index::process_count]
    if num_epochs != 1:
        dataset = dataset.repeat(num_epochs, reseed_each_epoch=True)
    dataset = dataset.map(lambda indexed: to_arrays(images.join(indexed[1]), max_answers, indexed[0]))
    dataset = dataset.batch(batch_size, drop_remainder=drop_remainder)
    # read_options: grain's read threads and prefetch buffer (its defaults read far ahead)
    return dataset.to_iter_dataset(read_options)


def process_shard() -> tuple[int, int]:
    """(process_index, process_count) of this JAX process."""
    import jax

    return jax.process_index(), jax.process_count()
