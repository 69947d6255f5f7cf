"""Write a dataset folder under a staging name and publish it with one rename.

A build writes everything (records, image tables, tokenizer, statistics) into a fresh hidden
staging folder beside the destination and renames it into place only once it is complete, so the
destination either does not exist or holds a finished dataset: an interrupted build leaves at most
a `.staging-*` folder, which no reader opens. A failed build removes its staging folder itself;
one killed outright leaves it behind, harmless, to be deleted by hand.
"""

from __future__ import annotations

import contextlib
import os
import pathlib
import shutil
import uuid
from typing import Iterator

STAGING_PREFIX = ".staging-"


@contextlib.contextmanager
def staged(data_dir, relative, overwrite: bool = False) -> Iterator[pathlib.Path]:
    """Yield a fresh staging root; when the block succeeds, move `root / relative` to
    `data_dir / relative`. An existing destination is replaced only with `overwrite`."""
    data_dir, relative = pathlib.Path(data_dir), pathlib.Path(relative)
    final = data_dir / relative
    root = data_dir / f"{STAGING_PREFIX}{os.getpid()}-{uuid.uuid4().hex[:8]}"
    root.mkdir(parents=True)
    try:
        yield root
        written = root / relative
        if not written.is_dir():
            raise FileNotFoundError(f"nothing was written at {written} to publish")
        final.parent.mkdir(parents=True, exist_ok=True)
        if final.exists():
            if not overwrite:
                raise FileExistsError(f"{final} appeared while this build ran (another build of the same dataset?)")
            final.rename(root / "replaced")  # thrown away with the staging root
        written.rename(final)
    finally:
        shutil.rmtree(root, ignore_errors=True)
