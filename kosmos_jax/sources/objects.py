"""Cornell's image -> physical object map, read from `processedData/z.txt`.

Each line of z.txt is `IMAGE OBJECT_ID CATEGORY BACKGROUND` (e.g. `0000 0 Aluminum_Can pcdb_0002`),
one line per labelled rectangle of an older annotation round, so an image repeats on many lines;
only the image -> (object id, category) map is kept. It is the grouping the honest object-wise
split uses. An image listed with two different objects, a malformed line or bytes that are not
UTF-8 raise ObjectMapFormatError naming the file and line.
"""

from __future__ import annotations

import pathlib
from typing import Mapping

from kosmos_jax.sources import text_file

ObjectMap = Mapping[str, tuple[int, str]]  # photo id ("pcd0100") -> (object id, category)

CANDIDATES = ("processedData/z.txt", "z.txt")


class ObjectMapFormatError(ValueError):
    """A z.txt line that cannot be read; the message names the file and line."""


def find_object_map(root: str | pathlib.Path) -> pathlib.Path | None:
    """root/processedData/z.txt or root/z.txt, whichever exists first, else None."""
    for candidate in CANDIDATES:
        path = pathlib.Path(root) / candidate
        if path.is_file():
            return path
    return None


def parse_object_map(text: str, source: str = "<text>") -> dict[str, tuple[int, str]]:
    """z.txt text -> {photo id: (object id, category)}, repeated lines merged."""
    mapping: dict[str, tuple[int, str]] = {}
    first_line: dict[str, int] = {}
    for number, line in enumerate(text_file.split_lines(text), start=1):
        fields = text_file.split_fields(line)
        if not fields:
            continue
        if len(fields) != 4:
            raise ObjectMapFormatError(
                f"{source}, line {number}: expected 'IMAGE OBJECT_ID CATEGORY BACKGROUND', got {line.strip()!r}")
        image, object_id, category, _ = fields
        if not (text_file.is_ascii_integer(image) and text_file.is_ascii_integer(object_id)):
            raise ObjectMapFormatError(
                f"{source}, line {number}: image and object id must be integers, got {line.strip()!r}")
        photo_id = f"pcd{int(image):04d}"
        entry = (int(object_id), category)
        if photo_id in mapping and mapping[photo_id] != entry:
            raise ObjectMapFormatError(
                f"{source}, line {number}: {photo_id} is object {entry}, but line "
                f"{first_line[photo_id]} says {mapping[photo_id]}")
        mapping[photo_id] = entry
        first_line.setdefault(photo_id, number)
    return mapping


def read_object_map(path: str | pathlib.Path) -> dict[str, tuple[int, str]]:
    path = pathlib.Path(path)
    return parse_object_map(text_file.read_text(path, ObjectMapFormatError), str(path))
