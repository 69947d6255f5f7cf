"""The build's inputs: the photos of a Cornell-format folder and the words of every object.

Words come from the --annotations file (the KOSMOS-E authors' file, or a synthetic_meta.json: it
has "photos"), else the source's synthetic_meta.json, else colour from pixels (rules), where a
photo whose pixels name no colour loses only its colour kinds, with the reason.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import pathlib

from kosmos_jax.annotators import kosmos_e as kosmos_e_words
from kosmos_jax.annotators import rules as rule_words
from kosmos_jax.annotators import synthetic as synthetic_words
from kosmos_jax.annotators.base import ObjectWords
from kosmos_jax.sources import cornell
from kosmos_jax.sources.kosmos_e_annotations import AnnotationMismatchError, parse_annotations

WORD_SOURCES = ("kosmos_e", "synthetic", "rules")
RULE_KINDS = ("non", "angle", "colour", "position", "multi-colour", "multi-position")


def read_photos(source: pathlib.Path) -> tuple[list, dict[str, pathlib.Path | None]]:
    """The photos under `source` and {photo id: its image file} (to name it in errors)."""
    if not source.is_dir():
        raise FileNotFoundError(f"source folder {source} does not exist")
    files = cornell.find_photos(source)
    object_map = cornell.resolve_object_map(source, "auto")
    photos = [cornell.read_photo(f, object_map=object_map) for f in files]
    if not photos:
        raise FileNotFoundError(f"no Cornell-format photos (pcdNNNNr.png with cpos.txt) under {source}")
    for photo in photos:
        if len(photo.grasps) == 0:
            raise ValueError(f"photo {photo.id} under {source} has no grasps (its cpos.txt is empty, missing or all NaN)")
    return photos, {f.id: f.rgb for f in files}


@dataclasses.dataclass(frozen=True)
class WordSource:
    """Where the objects' words come from, its file read once: "kosmos_e" or "synthetic" (`path`,
    its parsed JSON `document` and the sha256 of the bytes read) or "rules" (pixels, no file)."""

    name: str
    path: pathlib.Path | None = None
    document: object = None
    sha256: str | None = None


def word_source(source: pathlib.Path, annotations: str | None) -> WordSource:
    """The --annotations file (a KOSMOS-E file, or a synthetic_meta.json: it has "photos"), else
    the source's synthetic_meta.json, else rules; without reading the photos."""
    if annotations is not None:
        path = pathlib.Path(annotations)
        if not path.is_file():
            raise FileNotFoundError(f"annotation file {path} does not exist")
    else:
        path = source / "synthetic_meta.json"
        if not path.is_file():
            return WordSource("rules")
    data = path.read_bytes()
    try:
        document = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise AnnotationMismatchError(f"annotation file {path} is not JSON: {error}") from error
    synthetic = annotations is None or (isinstance(document, dict) and "photos" in document)
    return WordSource("synthetic" if synthetic else "kosmos_e", path, document, hashlib.sha256(data).hexdigest())


def _mismatch(path, message: str) -> AnnotationMismatchError:
    return AnnotationMismatchError(f"annotation file {path} does not match the photos: {message}")


def _kosmos_e(path: pathlib.Path, document, photos) -> dict:
    if not isinstance(document, dict):
        raise AnnotationMismatchError(f"{path}: expected a JSON object of photo keys, got {type(document).__name__}")
    annotations = parse_annotations(document, str(path))
    words = {}
    for photo in photos:
        if photo.id not in annotations:
            raise _mismatch(path, f"no entry for photo {photo.id}")
        words[photo.id] = kosmos_e_words.words_from_photo(annotations.attach(photo))
    return words


def _synthetic(path: pathlib.Path, document, photos) -> dict:
    words = synthetic_words.words_from_document(document, path)
    for photo in photos:
        if photo.id not in words:
            raise _mismatch(path, f"no entry for photo {photo.id}")
        parts = len(words[photo.id].parts)
        if parts != len(photo.grasps):
            raise _mismatch(path, f"photo {photo.id} has {len(photo.grasps)} grasps but {parts} grasp parts")
    return words


def _rules(photos, image_files: dict) -> dict:
    """Colour words from pixels: {photo id: ObjectWords}.

    A photo whose pixels name no colour gets its colour marked unknown, with the reason (its
    colour kinds are left out); anything else wrong with a photo is an error naming it and its file."""
    words = {}
    for photo in photos:
        where = f"photo {photo.id} ({image_files.get(photo.id) or 'no image file'})"
        try:
            words[photo.id] = rule_words.words_from_pixels(photo.rgb, photo.grasps)
        except rule_words.NoColourError as error:
            words[photo.id] = ObjectWords(unknown={"colour": f"{where}: {error}"})
        except ValueError as error:
            raise ValueError(f"{where}: {error}") from error
    return words


def object_words(words_from: WordSource, photos, image_files: dict) -> dict:
    """{photo id: ObjectWords} of every photo."""
    if words_from.name == "synthetic":
        return _synthetic(words_from.path, words_from.document, photos)
    if words_from.name == "kosmos_e":
        return _kosmos_e(words_from.path, words_from.document, photos)
    return _rules(photos, image_files)


def words_unknown(words: dict) -> dict:
    """{photo id: {"kinds": [...], "reason": ...}} of the photos whose words mark kinds unknown."""
    return {photo: {"kinds": sorted(w.unknown), "reason": "; ".join(dict.fromkeys(w.unknown.values()))}
            for photo, w in sorted(words.items()) if w.unknown}
