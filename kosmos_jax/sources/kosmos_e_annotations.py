"""KOSMOS-E's instruction annotations of the Cornell photos (`instructions-original.json`).

The file has keys "0".."884", key i describing the i-th photo of the SORTED full 885-photo Cornell
set (cornell_set.FULL_SET_IDS: pcd0100..pcd0949, pcd1000..pcd1034), whatever subset is present locally.
Its `instruction_part` has one sentence per non-NaN rectangle of that photo's cpos.txt, in file
order, so it lines up with Photo.grasps; `attach` checks the count and raises
AnnotationMismatchError naming the photo when it differs.

Keys put into Photo.annotations:
  "name"      the object's name, a noun phrase ("remote control"; `obj_name`)
  "colour"    the colour instruction sentence ("Grasp the black object."; `instruction_color`)
  "shape"     the shape instruction sentence (`instruction_shape`)
  "purpose"   the purpose instruction sentence (`instruction_purpose`)
  "strategy"  the grasping-strategy sentence(s) (`instruction_strategy`)
  "parts"     list of part instruction sentences, one per grasp, aligned with Photo.grasps
  "instructions"  the photo's raw entry: {"obj_name", "instruction_name", "instruction_color",
              "instruction_shape", "instruction_purpose", "instruction_strategy",
              "instruction_part": {"0": ..., ...}} exactly as in the file
The sentences are kept verbatim (typos such as "Grsap" included): they are what the model reads.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
from typing import Any, Mapping, Sequence

from kosmos_jax.sources import text_file
from kosmos_jax.sources.cornell_set import FULL_SET_IDS
from kosmos_jax.sources.photo import Photo

FIELDS = {
    "name": "obj_name",
    "colour": "instruction_color",
    "shape": "instruction_shape",
    "purpose": "instruction_purpose",
    "strategy": "instruction_strategy",
}
REQUIRED_KEYS = (*FIELDS.values(), "instruction_name", "instruction_part")


class AnnotationMismatchError(ValueError):
    """Annotations that do not line up with a photo's grasps (or a malformed annotation file)."""


@dataclasses.dataclass(frozen=True)
class KosmosEAnnotations:
    """The raw entries by photo id, in the full-set order."""

    entries: Mapping[str, Mapping[str, Any]]
    source: str = "<memory>"

    def __contains__(self, photo_id: str) -> bool:
        return photo_id in self.entries

    def for_photo(self, photo_id: str, num_grasps: int) -> dict[str, Any]:
        """The annotation dict for `photo_id` (keys in the module docstring), checked against
        the photo's number of kept grasps."""
        if photo_id not in self.entries:
            raise KeyError(f"{self.source}: no KOSMOS-E annotation for photo {photo_id}")
        entry = self.entries[photo_id]
        parts = [entry["instruction_part"][key] for key in sorted(entry["instruction_part"], key=int)]
        if len(parts) != num_grasps:
            raise AnnotationMismatchError(
                f"photo {photo_id}: {self.source} has {len(parts)} part instructions "
                f"(key {FULL_SET_IDS.index(photo_id)}) but the photo has {num_grasps} grasps "
                "after dropping NaN rectangles")
        annotation = {ours: entry[theirs] for ours, theirs in FIELDS.items()}
        annotation["parts"] = parts
        annotation["instructions"] = dict(entry)
        return annotation

    def attach(self, photo: Photo) -> Photo:
        """A copy of `photo` with these annotations merged into Photo.annotations."""
        annotation = self.for_photo(photo.id, len(photo.grasps))
        return dataclasses.replace(photo, annotations={**photo.annotations, **annotation})


def parse_annotations(raw: Mapping[str, Any], source: str = "<memory>") -> KosmosEAnnotations:
    """The JSON object (keys "0".."884") -> annotations keyed by photo id."""
    expected = {str(i) for i in range(len(FULL_SET_IDS))}
    if set(raw) != expected:
        unexpected = sorted(set(raw) - expected)[:5]
        missing = sorted(expected - set(raw), key=int)[:5]
        raise AnnotationMismatchError(
            f"{source}: keys must be \"0\"..\"{len(FULL_SET_IDS) - 1}\" (one per photo of the sorted "
            f"885-photo Cornell set); missing {missing}, unexpected {unexpected}")
    entries = {}
    for index, photo_id in enumerate(FULL_SET_IDS):
        entry = raw[str(index)]
        absent = [key for key in REQUIRED_KEYS if key not in entry]
        if absent:
            raise AnnotationMismatchError(f"{source}: key \"{index}\" ({photo_id}) lacks {absent}")
        part_keys = sorted(entry["instruction_part"], key=int)
        if part_keys != [str(i) for i in range(len(part_keys))]:
            raise AnnotationMismatchError(
                f"{source}: key \"{index}\" ({photo_id}) instruction_part keys {part_keys} are not 0..n-1")
        entries[photo_id] = entry
    return KosmosEAnnotations(entries, source)


def read_annotations(path: str | pathlib.Path) -> KosmosEAnnotations:
    path = pathlib.Path(path)
    text = text_file.read_text(path, AnnotationMismatchError)
    try:
        raw = json.loads(text)
    except json.JSONDecodeError as error:
        raise AnnotationMismatchError(
            f"{path}, line {error.lineno}, column {error.colno}: not valid JSON ({error.msg})") from None
    if not isinstance(raw, dict):
        raise AnnotationMismatchError(f"{path}: expected a JSON object of photo keys, got {type(raw).__name__}")
    return parse_annotations(raw, str(path))


def read_object_names(path: str | pathlib.Path) -> dict[str, str]:
    """KOSMOS-E's obj_names.txt (one name per line, full-set order) -> {photo id: name}."""
    path = pathlib.Path(path)
    names = text_file.split_lines(text_file.read_text(path, AnnotationMismatchError))
    if len(names) != len(FULL_SET_IDS):
        raise AnnotationMismatchError(f"{path}: {len(names)} names, expected {len(FULL_SET_IDS)}")
    return dict(zip(FULL_SET_IDS, names))


def attach_all(photos: Sequence[Photo], annotations: KosmosEAnnotations) -> list[Photo]:
    return [annotations.attach(photo) for photo in photos]
