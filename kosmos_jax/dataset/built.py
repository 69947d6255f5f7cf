"""A built dataset's folder as its readers open it: its build statistics (build_stats.json, which
holds the data identity), its tokenizer and its stored splits. The trainer, the evaluation and
prediction open a dataset here; dataset/build.py writes one.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

from kosmos_jax.dataset import tfds_builders
from kosmos_jax.text.tokenizer import Tokenizer, load_tokenizer

STATS_FILE = "build_stats.json"


@dataclasses.dataclass(frozen=True)
class Dataset:
    """A built dataset: its folder, build statistics and tokenizer."""

    dir: pathlib.Path
    stats: dict

    @property
    def identity(self) -> dict:
        return self.stats["identity"]

    @property
    def tokenizer_path(self) -> pathlib.Path:
        path = pathlib.Path(self.stats["tokenizer"].get("path") or self.dir / "tokenizer.model")
        if not path.is_file():
            raise FileNotFoundError(f"the tokenizer of dataset {self.dir} is missing ({path})")
        return path

    def tokenizer(self) -> Tokenizer:
        info = self.stats["tokenizer"]
        return load_tokenizer(self.tokenizer_path, scheme=info["scheme"], numbers=info["numbers"])

    def splits(self) -> dict:
        return tfds_builders.open_splits(self.dir)


def open_dataset(folder) -> Dataset:
    folder = pathlib.Path(folder)
    stats_file = folder / STATS_FILE
    if not stats_file.is_file():
        raise FileNotFoundError(f"{folder} is not a built dataset (no {STATS_FILE}); "
                                "build one with python -m kosmos_jax.dataset.build or leave config.data.dir empty")
    return Dataset(folder, json.loads(stats_file.read_text()))
