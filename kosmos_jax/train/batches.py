"""The trainer's data: the dataset a config names (built on first use, reused after), and its batches.

`prepare(config.data)` returns the dataset folder and its build statistics: config.data.dir when
given, else the build of config.data.build from config.data.source ("synthetic": scenes the
project writes under config.data.root; "cornell": ../shared/data/cornell; or a folder), written
under config.data.root and reused when an identical build is there. Each process reads the
batches of its own rows of every global batch (grain shards by process).
"""

from __future__ import annotations

import pathlib
import sys

import numpy as np

from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.dataset import build as build_lib
from kosmos_jax.dataset import pipeline
from kosmos_jax.dataset.built import Dataset, open_dataset

REPO = pathlib.Path(__file__).resolve().parents[2]
SHARED_CORNELL = REPO.parent / "shared" / "data" / "cornell"


def source_folder(data_config) -> pathlib.Path:
    """The Cornell-format folder the build reads, writing the synthetic scenes first if asked for."""
    source = data_config.source
    if source == "synthetic":
        folder = pathlib.Path(data_config.root) / f"synthetic-{data_config.synthetic_photos}-seed{data_config.synthetic_seed}"
        if (folder / scenes.META_NAME).is_file():
            return folder
        print(f"writing {data_config.synthetic_photos} synthetic photos to {folder}", file=sys.stderr, flush=True)
        scenes.write_dataset(folder, photos=data_config.synthetic_photos, seed=data_config.synthetic_seed,
                             overwrite=True, progress=True)
        return folder
    folder = SHARED_CORNELL if source == "cornell" else pathlib.Path(source)
    if not folder.is_dir():
        raise FileNotFoundError(f"data source {source!r}: folder {folder} does not exist")
    return folder


def kind_names(kinds):
    """A config's instruction kinds as the build takes them: "non, multi" -> ("non", "multi"); a sequence as it is."""
    return tuple(k.strip() for k in kinds.split(",")) if isinstance(kinds, str) else kinds


def build_config(data_config) -> build_lib.BuildConfig:
    settings = data_config.build.to_dict()
    settings["kinds"] = kind_names(settings.pop("kinds"))
    for name in ("annotations", "tokenizer"):
        if settings.get(name):
            path = pathlib.Path(settings[name])
            settings[name] = str(path if path.is_absolute() or path.exists() else REPO / path)
    return build_lib.BuildConfig(source=str(source_folder(data_config)), out=str(data_config.root), **settings)


def prepare(data_config) -> Dataset:
    """The dataset of `data_config`, built (or found) on this process's file system."""
    if data_config.dir:
        return open_dataset(data_config.dir)
    stats = build_lib.build(build_config(data_config))
    print(f"dataset {'reused' if stats.get('reused') else 'built'}: {stats['dataset_dir']}", file=sys.stderr, flush=True)
    return open_dataset(stats["dataset_dir"])


def kind_repeats(text: str) -> dict[str, int]:
    """config.data.kind_repeats, "non=3[,multi-name=2...]" -> {kind: times an epoch draws each of its
    examples}; "" -> {} (each example once)."""
    repeats = {}
    for item in filter(None, (part.strip() for part in str(text or "").split(","))):
        kind, equals, times = item.partition("=")
        if not equals or not kind.strip() or not times.strip().isdigit() or int(times) < 1:
            raise ValueError(f"config.data.kind_repeats: {item!r} is not KIND=N with N a whole number >= 1 "
                             f"(e.g. non=3)")
        if kind.strip() in repeats:
            raise ValueError(f"config.data.kind_repeats names {kind.strip()!r} twice")
        repeats[kind.strip()] = int(times)
    return repeats


def repeated_order(split, repeats: dict[str, int]) -> np.ndarray | None:
    """The example indices an epoch of `split` draws from: each example of a kind in `repeats` that many
    times, the others once (None when `repeats` is empty). A kind the split does not hold is refused."""
    if not repeats:
        return None
    kinds = [bytes(record["kind"]).decode() for record in split.examples]
    missing = sorted(set(repeats) - set(kinds))
    if missing:
        raise ValueError(f"config.data.kind_repeats names {', '.join(map(repr, missing))}, which the training split "
                         f"does not hold (its kinds: {', '.join(sorted(set(kinds)))})")
    return np.repeat(np.arange(len(kinds)), [repeats.get(kind, 1) for kind in kinds])


def train_batches(split, global_batch: int, seed: int, process_index: int, process_count: int,
                  repeats: dict[str, int] | None = None):
    """Endless batches of this process's rows of each global batch (an iterator with get_state/set_state);
    `repeats` ({kind: N}, kind_repeats) draws each example of those kinds N times an epoch."""
    if global_batch % process_count:
        raise ValueError(f"train.batch_size={global_batch} is not divisible by the {process_count} processes")
    if len(split) < global_batch:
        raise ValueError(f"the training split has {len(split)} examples, fewer than one batch of {global_batch}")
    dataset = pipeline.make_dataset(split, global_batch // process_count, seed=seed, process_index=process_index,
                                    process_count=process_count, num_epochs=None,
                                    order=repeated_order(split, repeats or {}))
    return iter(dataset)


def eval_batches(split, global_batch: int, process_index: int, process_count: int, max_batches: int = 0):
    """The test split in order, in batches of this process's rows; the last batch padded with rows
    whose loss mask is empty (they weigh nothing). `max_batches` > 0 stops early."""
    local = global_batch // process_count
    dataset = pipeline.make_dataset(split, local, shuffle=False, process_index=process_index,
                                    process_count=process_count, num_epochs=1, drop_remainder=False)
    for number, batch in enumerate(dataset):
        if max_batches and number >= max_batches:
            return
        yield pad_rows(batch, local)


def pad_rows(batch: dict, rows: int) -> dict:
    """`batch` with rows repeated up to `rows`, the copies' loss masks emptied."""
    have = len(batch["tokens"])
    if have == rows:
        return batch
    take = np.arange(rows) % have
    padded = {name: value[take] for name, value in batch.items()}
    padded["loss_mask"][have:] = False
    padded["example_index"][have:] = -1
    return padded


def describe_examples(split, example_index) -> list[str]:
    """'photo ids (kind)' of each example of a batch, by its example_index."""
    out = []
    for index in np.asarray(example_index).tolist():
        if index < 0:
            continue
        record = split.examples[int(index)]
        photos = [bytes(p).decode() for p in record["photo_ids"]]
        out.append(f"{'+'.join(photos)} ({bytes(record['kind']).decode()})")
    return out
