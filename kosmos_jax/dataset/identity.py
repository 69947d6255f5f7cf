"""A dataset's identity: a canonical JSON of everything that decides its contents, and a short hash.

Two builds share a dataset folder only when their identities are equal, so the identity must name
every input that changes a byte of the data: the settings, and the files read (by content, not
just by path: a folder edited in place is another input).
"""

from __future__ import annotations

import hashlib
import json
import pathlib
from typing import Any

HASH_LENGTH = 12  # hex digits of the name's hash: 48 bits; the full identity is compared on reuse


def canonical(value: Any) -> str:
    """Canonical JSON: sorted keys, no spaces; tuples become lists."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False)


def normalised(value: Any) -> Any:
    """`value` as it reads back from JSON, so a fresh identity compares equal to a stored one."""
    return json.loads(canonical(value))


def short_hash(value: Any, length: int = HASH_LENGTH) -> str:
    return hashlib.sha256(canonical(value).encode()).hexdigest()[:length]


def _file_sha256(path: pathlib.Path, into) -> None:
    with path.open("rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            into.update(block)


def content_digest(path) -> str:
    """sha256 of a file's bytes, or of a folder's files: each one's relative path, size and bytes,
    in sorted path order (so renaming, adding or editing any file changes it)."""
    path = pathlib.Path(path)
    digest = hashlib.sha256()
    if path.is_file():
        _file_sha256(path, digest)
        return digest.hexdigest()
    if not path.is_dir():
        raise FileNotFoundError(f"{path} does not exist")
    for file in sorted((f for f in path.rglob("*") if f.is_file()), key=lambda f: f.relative_to(path).as_posix()):
        digest.update(f"{file.relative_to(path).as_posix()}\0{file.stat().st_size}\0".encode())
        _file_sha256(file, digest)
    return digest.hexdigest()
