"""What must hold of a built dataset: every example's target, the split separation, the bytes written."""

from __future__ import annotations

import math
import pathlib
import re

import numpy as np

from kosmos_jax import geometry
from kosmos_jax.dataset import images as image_table
from kosmos_jax.dataset import tfds_builders
from kosmos_jax.text.formatter import FormatConfig, parse_target

SPOT_CHECKS = 32


class BuildCheckError(AssertionError):
    """A built example breaks one of the must-hold properties."""


_ANGLE_CODE = re.compile(r"a_(-?\d+)\b")


def check_example(example, config: FormatConfig) -> None:
    grasp, size = example.grasp, config.image_size
    where = f"sample of photos {example.photo_ids} ({example.kind}, {example.part}): "
    if not (0 <= grasp[0] < size and 0 <= grasp[1] < size):
        raise BuildCheckError(where + f"target grasp centre ({grasp[0]:.2f}, {grasp[1]:.2f}) outside the {size} image")
    if config.angle_code:
        for code in _ANGLE_CODE.findall(example.target_text):
            if not 0 <= int(code) <= 255:
                raise BuildCheckError(where + f"angle code {code} outside [0, 255]")
    parsed = parse_target(example.target_text, example.part, config)
    if not parsed.ok:
        raise BuildCheckError(where + f"target {example.target_text!r} does not parse: {parsed.error}")
    stated = example.grasp_mask
    if stated[4]:
        # the code clips at 255, so an angle in the last half bin below pi/2 is one bin off
        tolerance = math.pi / geometry.ANGLE_BINS if config.angle_code else 0.005
        if geometry.angle_difference(parsed.grasp[4], grasp[4]) > tolerance + 1e-9:
            raise BuildCheckError(where + f"target {example.target_text!r} gives angle {parsed.grasp[4]:.4f}, not {grasp[4]:.4f}")
    if stated[0] and config.representation != "tlbra_patch":
        # the formatter prints centres clipped to [0, size - 1]
        expected = np.clip(grasp[:2], 0, size - 1)
        if np.any(np.abs(parsed.grasp[:2] - expected) > 0.5 + 1e-9):
            raise BuildCheckError(where + f"target {example.target_text!r} gives centre {parsed.grasp[:2]}, not {grasp[:2]}")


def _shared(ids: dict, held: str, other: str, protocol: str, split: str) -> dict:
    """Photo and object ids of split `held` found in split `other`; an error in the honest protocol."""
    photos = sorted(set(ids[other]["photos"]) & set(ids[held]["photos"]))
    objects = sorted(set(ids[other]["objects"]) & set(ids[held]["objects"]))
    if protocol == "honest":
        reach = "training" if other == "train" else other
        if photos:
            raise BuildCheckError(f"{held} photos {photos[:5]} reach {reach} samples")
        if split == "object" and objects:
            raise BuildCheckError(f"{held} objects {objects[:5]} reach {reach} samples")
    return {"shared_photos": len(photos), "shared_objects": len(objects)}


def check_separation(ids: dict, protocol: str, split: str) -> dict:
    """Overlaps of the splits' photo and object ids; an error in the honest protocol. Train against
    test at the top level; with a validation split, also "validation": {"train": ..., "test": ...},
    validation's overlaps with each."""
    found = _shared(ids, "test", "train", protocol, split)
    if "validation" in ids:
        found["validation"] = {other: _shared(ids, "validation", other, protocol, split) for other in ("train", "test")}
    return found



def spot_numbers(count: int, checks: int = SPOT_CHECKS) -> set[int]:
    """About `checks` example numbers spread over 0..count-1, the first and last included."""
    if count <= 0:
        return set()
    return {int(n) for n in np.linspace(0, count - 1, min(count, checks)).round()}


def check_written(dataset_dir: pathlib.Path, examples: dict[str, int], spots: dict[str, dict[int, bytes]]) -> dict:
    """Re-read a written dataset: each split's example count, its image table, and the images joined
    to the spot-checked examples against the digests of the images they were made from.
    Returns {split: distinct images stored}."""
    found = {}
    for split, stored in tfds_builders.open_splits(dataset_dir).items():
        if len(stored) != examples[split]:
            raise BuildCheckError(f"split {split!r} holds {len(stored)} examples on disk, {examples[split]} were made")
        if not 0 < len(stored.images) <= len(stored):
            raise BuildCheckError(f"split {split!r} stores {len(stored.images)} images for {len(stored)} examples")
        for number, want in spots[split].items():
            record = stored[number]
            if image_table.digest(record["image"]) != want:
                raise BuildCheckError(f"example {number} of split {split!r} ({bytes(record['kind']).decode()}, photos "
                                      f"{[bytes(p).decode() for p in record['photo_ids']]}) joins image "
                                      f"{int(record['image_index'])}, not the image it was made from")
        found[split] = len(stored.images)
    return found
