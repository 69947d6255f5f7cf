"""The record every reader produces and every later stage consumes."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np


@dataclasses.dataclass
class Photo:
    """One labelled photo.

    id: the dataset's own name ("pcd0100" for Cornell, "0_2f48..." for Jacquard).
    rgb: [H, W, 3] uint8, RGB order; None when read with load_images=False.
    depth: [H, W] float32 or None.
    grasps: [N, 5] float64 positive grasps (x, y, w, h, theta) in photo pixels, file order, NaN
      rectangles already dropped.
    negatives: [K, 5] float64 negative grasps (Cornell's cneg.txt), possibly empty.
    object_id: the physical object's id (Cornell's z.txt number, Jacquard's hex name), or None.
    category: the object's category name, or None.
    annotations: words about the object from an annotator (name, colour, shape, purpose,
      strategy, parts aligned with `grasps`, ...); empty when none was attached.
    nan_dropped: how many rectangles of the file had a NaN corner and were dropped.
    """

    id: str
    rgb: np.ndarray | None
    depth: np.ndarray | None
    grasps: np.ndarray
    negatives: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 5)))
    object_id: int | str | None = None
    category: str | None = None
    annotations: dict[str, Any] = dataclasses.field(default_factory=dict)
    nan_dropped: int = 0

    @property
    def height(self) -> int:
        return int(self._image().shape[0])

    @property
    def width(self) -> int:
        return int(self._image().shape[1])

    def _image(self) -> np.ndarray:
        if self.rgb is None:
            raise ValueError(f"photo {self.id} was read without its image (load_images=False)")
        return self.rgb
