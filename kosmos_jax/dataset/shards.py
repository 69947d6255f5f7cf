"""Serialized records streamed into array_record shards of a fixed size, in write order.

Each shard is written under a hidden part name and renamed to its final name (which holds the
shard count, e.g. "...-00001-of-00003") only when the writer is closed, so shards of an
unfinished write never carry a final name.
"""

from __future__ import annotations

import pathlib
from typing import Callable

from array_record.python import array_record_module

# group_size 1: every record is its own chunk, so random access reads one record, not a group
WRITER_OPTIONS = "group_size:1"


class ShardWriter:
    """Appends bytes records to shards of `shard_records` each; `close()` gives the final paths.

    `final_path(index, count)` names shard `index` of `count`.
    """

    def __init__(self, folder, stem: str, final_path: Callable[[int, int], pathlib.Path], shard_records: int):
        if shard_records < 1:
            raise ValueError(f"shard_records must be positive, got {shard_records}")
        self.folder, self.stem, self.final_path, self.shard_records = pathlib.Path(folder), stem, final_path, shard_records
        self.lengths: list[int] = []
        self.num_bytes = 0
        self._parts: list[pathlib.Path] = []
        self._writer = None

    def __len__(self) -> int:
        return sum(self.lengths)

    def write(self, data: bytes) -> int:
        """Append one record; returns its index among all the records written."""
        if self._writer is None:
            self._parts.append(self.folder / f".{self.stem}-part{len(self._parts):05d}")
            self._writer = array_record_module.ArrayRecordWriter(str(self._parts[-1]), WRITER_OPTIONS)
            self.lengths.append(0)
        self._writer.write(data)
        self.num_bytes += len(data)
        self.lengths[-1] += 1
        if self.lengths[-1] == self.shard_records:
            self._close_part()
        return len(self) - 1

    def _close_part(self) -> None:
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def close(self) -> list[pathlib.Path]:
        """Finish the last shard and give every shard its final name; the final paths in order."""
        self._close_part()
        finals = [self.final_path(index, len(self._parts)) for index in range(len(self._parts))]
        for part, final in zip(self._parts, finals):
            part.rename(final)
        return finals

    def abandon(self) -> None:
        """Close without naming: the parts stay hidden (their folder is thrown away)."""
        self._close_part()
