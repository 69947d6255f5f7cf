"""The records of the instruction stage: a View goes in, a Sample comes out."""

from __future__ import annotations

import dataclasses

import numpy as np

from kosmos_jax.annotators.base import ObjectWords


@dataclasses.dataclass(frozen=True)
class View:
    """One augmented photo: its image, its grasps in that image's pixels and its object's words.

    grasp_ids: for each row of `grasps`, its index in the photo's own grasp list, so that
      per-grasp words (`ObjectWords.parts`) stay aligned after augmentation drops grasps.
      None means rows are the photo's grasps in order.
    """

    photo_id: str
    image: np.ndarray
    grasps: np.ndarray
    words: ObjectWords | None = None
    object_id: int | None = None
    grasp_ids: np.ndarray | None = None

    def ids(self) -> np.ndarray:
        n = np.asarray(self.grasps).shape[0]
        return np.arange(n) if self.grasp_ids is None else np.asarray(self.grasp_ids, np.int64)


@dataclasses.dataclass(frozen=True)
class Sample:
    """One INSTRUCT-GRASP sample before formatting.

    kind: "non" or an instruction kind; scene: "non", "single" or "multi".
    instruction: the sentence ("" for NON). answer: "grasp" or "centre" (angle instructions).
    grasps: [N, 5] every grasp in `image` pixels that answers the instruction; for a per-grasp
      kind (angle, part) the grasp the sentence was made from is row 0.
    photo_ids / object_ids: every photo whose pixels are in `image` (a mosaic: all four, in
      quadrant order), so that a split can be checked for leaks. target: index of the photo the
      instruction refers to. redraws: distractors rejected as ambiguous while building a mosaic.
    """

    kind: str
    scene: str
    instruction: str
    answer: str
    image: np.ndarray
    grasps: np.ndarray
    photo_ids: tuple[str, ...]
    object_ids: tuple[int | None, ...]
    target: int = 0
    redraws: int = 0
