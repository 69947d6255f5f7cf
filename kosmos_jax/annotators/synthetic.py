"""Words from the synthetic scenes' metadata (`synthetic_meta.json`, kosmos_jax.sources.synthetic).

Per photo the metadata holds name, colour (list) and colour_phrase ("red with white details"),
shape (adjectives) and shape_phrase ("cylindrical object with a handle"), purpose, strategy,
and grasp_parts: the part name of every positive grasp in cpos.txt order. Its "position" word
describes the whole 640 x 480 photo, so it is not used: positions are derived from the grasps of
each augmented view (kosmos_jax.instruct.position).
"""

from __future__ import annotations

import json
import pathlib
from typing import Any, Mapping

from kosmos_jax.annotators.base import ObjectWords
from kosmos_jax.annotators.kosmos_e import slot_words

REQUIRED = ("name", "colour_phrase", "shape_phrase", "purpose", "strategy", "grasp_parts")


def words_from_meta(meta: Mapping[str, Any], photo_id: str = "?") -> ObjectWords:
    """ObjectWords of one photo's metadata record."""
    missing = [key for key in REQUIRED if key not in meta]
    if missing:
        raise ValueError(f"synthetic metadata of photo {photo_id!r} lacks {missing}")
    shape_sentence = f"Grasp the {meta['shape_phrase']}."
    return ObjectWords(
        name=meta["name"],
        colour=meta["colour_phrase"],
        shape=slot_words("shape", shape_sentence),
        purpose=meta["purpose"],
        strategy=meta["strategy"],
        parts=tuple(meta["grasp_parts"]),
        sentences={"shape": shape_sentence},
    )


def read_meta_words(path: str | pathlib.Path) -> dict[str, ObjectWords]:
    """{photo id ("pcd0100"): ObjectWords} from a synthetic dataset's metadata file (or its folder)."""
    path = pathlib.Path(path)
    if path.is_dir():
        path = path / "synthetic_meta.json"
    return words_from_document(json.loads(path.read_text()), path)


def words_from_document(document: Any, source: str | pathlib.Path = "<memory>") -> dict[str, ObjectWords]:
    """{photo id: ObjectWords} from the parsed JSON of a metadata file (`source` names it in errors)."""
    photos = document.get("photos") if isinstance(document, dict) else None
    if not isinstance(photos, dict):
        raise ValueError(f"{source}: no 'photos' object; not a synthetic_meta.json")
    return {photo_id: words_from_meta(meta, f"{source}:{photo_id}") for photo_id, meta in photos.items()}
