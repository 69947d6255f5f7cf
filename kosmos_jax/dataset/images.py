"""The image table of a split: each distinct image stored once, examples refer to it by index.

About 40 examples share one image (every instruction kind of an augmented view, centre and angle
apart; the examples of a mosaic), so storing the image with each example repeated it ~40 times.
A table is array_record shards of PNG bytes ("images-<split>.array_record-NNNNN-of-NNNNN"),
in first-use order; an example's `image_index` is its image's row. Reading needs no TensorFlow:
array_record's own data source and OpenCV's PNG decoder.

Writing interns images: the same array object as the previous one (the examples of one sample
share it) is the same row; otherwise a content digest finds an equal image written before. A new
image's PNG is encoded on a worker thread (OpenCV's encoder releases the GIL, so the build's
examples are made meanwhile) and written in first-use order, the bytes and rows those of a
single-threaded write.
"""

from __future__ import annotations

import collections
import dataclasses
import hashlib
import os
import pathlib
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Mapping, Sequence

import cv2
import numpy as np
from array_record.python import array_record_data_source

from kosmos_jax.dataset.shards import ShardWriter

SHARD_IMAGES = 1024
ENCODERS = min(4, os.cpu_count() or 1)  # threads encoding PNGs while the build goes on
PENDING_IMAGES = 64  # encodings in flight before the writer waits for the oldest


def png_bytes(rgb: np.ndarray) -> bytes:
    """RGB uint8 [H, W, 3] -> PNG bytes (OpenCV writes BGR, hence the flip)."""
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an RGB uint8 [H, W, 3] image, got {rgb.dtype} {rgb.shape}")
    # level 1 with zlib's run-length strategy: on synthetic views and their mosaics 1.24x faster than
    # level 1's default strategy (itself about 3x faster than OpenCV's default level 3), 11% smaller,
    # and no slower to decode (benchmarks/png_images.py, 2 quiet cores)
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]),
                               [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE])
    if not ok:
        raise ValueError(f"OpenCV could not encode an image of shape {rgb.shape} as PNG")
    return encoded.tobytes()


def decode_png(data: bytes) -> np.ndarray:
    """PNG bytes -> RGB uint8 [H, W, 3]."""
    bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise ValueError(f"{len(data)} bytes that OpenCV cannot decode as an image")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def digest(image: np.ndarray) -> bytes:
    """A content digest of an array: equal for equal shape, dtype and pixels."""
    image = np.ascontiguousarray(image)
    hasher = hashlib.blake2b(f"{image.dtype.str}{image.shape}".encode(), digest_size=16)
    hasher.update(image.data)
    return hasher.digest()


def table_path(folder, split: str, index: int, count: int) -> pathlib.Path:
    return pathlib.Path(folder) / f"images-{split}.array_record-{index:05d}-of-{count:05d}"


class ImageTableWriter:
    """Writes the distinct images of one split; `index(image)` gives an image's row."""

    def __init__(self, folder, split: str, shape: tuple[int, ...], shard_images: int = SHARD_IMAGES,
                 encoders: int = ENCODERS):
        self.split, self.shape = split, tuple(shape)
        self._shards = ShardWriter(folder, f"images-{split}", lambda i, n: table_path(folder, split, i, n), shard_images)
        self._rows: dict[bytes, int] = {}
        self._last: tuple[Any, int] | None = None
        self._encoders = ThreadPoolExecutor(encoders, thread_name_prefix=f"png-{split}") if encoders > 1 else None
        self._pending: collections.deque[Future] = collections.deque()

    def index(self, image: np.ndarray) -> int:
        if self._last is not None and image is self._last[0]:
            return self._last[1]
        if np.shape(image) != self.shape:
            raise ValueError(f"image of shape {np.shape(image)} in split {self.split!r}, whose images are {self.shape}")
        key = digest(image)
        row = self._rows.get(key)
        if row is None:
            row = self._rows[key] = len(self._rows)
            self._encode(image)
        self._last = (image, row)  # holds the array, so its id cannot be reused meanwhile
        return row

    def _encode(self, image: np.ndarray) -> None:
        if self._encoders is None:
            self._shards.write(png_bytes(image))
            return
        self._pending.append(self._encoders.submit(png_bytes, np.array(image)))  # a copy: the caller may reuse it
        while len(self._pending) > PENDING_IMAGES:
            self._shards.write(self._pending.popleft().result())

    def _finish_encoding(self) -> None:
        while self._pending:
            self._shards.write(self._pending.popleft().result())
        if self._encoders is not None:
            self._encoders.shutdown()

    def close(self) -> dict:
        """Name the shards; the table's description for the dataset's metadata."""
        self._finish_encoding()
        paths = self._shards.close()
        return {"files": [p.name for p in paths], "shard_lengths": list(self._shards.lengths),
                "num_bytes": self._shards.num_bytes, "shape": list(self.shape)}

    def abandon(self) -> None:
        self._pending.clear()  # shutdown cancels the encodings not started; a started one ends unread
        if self._encoders is not None:
            self._encoders.shutdown(cancel_futures=True)
        self._shards.abandon()


class ImageTable:
    """Random access to one split's stored images, decoded: `table[i]` is uint8 [S, S, 3]."""

    def __init__(self, folder, description: Mapping):
        folder = pathlib.Path(folder)
        paths = [folder / name for name in description["files"]]
        missing = [str(p) for p in paths if not p.is_file()]
        if missing:
            raise FileNotFoundError(f"image table files missing: {missing[:3]}")
        self.shape = tuple(description["shape"])
        self._source = array_record_data_source.ArrayRecordDataSource([str(p) for p in paths])
        expected = sum(description["shard_lengths"])
        if len(self._source) != expected:
            raise ValueError(f"image table of {folder} holds {len(self._source)} images, its metadata says {expected}")

    def __len__(self) -> int:
        return len(self._source)

    def __getitem__(self, index: int) -> np.ndarray:
        image = decode_png(self._source[int(index)])
        if image.shape != self.shape:
            raise ValueError(f"stored image {index} has shape {image.shape}, not {self.shape}")
        return image

    def join(self, record: Mapping) -> dict:
        """An example record with its image put back under "image"."""
        return {**record, "image": self[record["image_index"]]}


@dataclasses.dataclass(frozen=True)
class StoredSplit:
    """One written split: `examples` (records with `image_index`, no pixels) and their `images`.

    `split[i]` is example i with its image joined back, as one record."""

    examples: Sequence[Mapping]
    images: ImageTable

    def __len__(self) -> int:
        return len(self.examples)

    def __getitem__(self, index: int) -> dict:
        return self.images.join(self.examples[index])
