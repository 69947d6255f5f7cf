"""Write a folder under a staging name and publish it with one rename.

A writer makes everything (records, image tables, tokenizer, statistics; or a synthetic photo set)
in a fresh hidden staging folder beside the destination and renames it into place only once it is
complete, so the destination either does not exist or holds a finished folder: an interrupted
writer leaves at most a `.staging-*` folder, which no reader opens. A failed writer removes its
staging folder itself. One killed outright leaves it behind; its name carries the destination, the
host and the writer's process id, so the next writer of the same destination on this host deletes
it once that process has ended.

Replacing a destination moves the old folder into the staging folder (thrown away with it) and
renames the new one in; entries of the old folder that `keep` chooses move into the new one first.
If that last rename fails, the old folder is put back as it was.
"""

from __future__ import annotations

import contextlib
import glob
import os
import pathlib
import shutil
import socket
import tempfile
import uuid
from typing import Callable, Iterator

STAGING_PREFIX = ".staging-"


def staging_prefix(relative) -> str:
    """Start of the staging names of the writers of `relative` on this host; the pid follows."""
    return f"{STAGING_PREFIX}{'+'.join(pathlib.Path(relative).parts)}-{socket.gethostname()}-"


@contextlib.contextmanager
def staged(data_dir, relative, overwrite: bool = False, *,
           keep: Callable[[pathlib.Path], bool] | None = None) -> Iterator[pathlib.Path]:
    """Yield a fresh staging root; when the block succeeds, move `root / relative` to
    `data_dir / relative`. An existing destination is replaced only with `overwrite`, and then
    the entries of it for which `keep(entry)` is true move into the new folder (they must be
    names the new folder does not have)."""
    data_dir, relative = pathlib.Path(data_dir), pathlib.Path(relative)
    final = data_dir / relative
    prefix = staging_prefix(relative)
    remove_stale(data_dir, prefix)
    root = data_dir / f"{prefix}{os.getpid()}-{uuid.uuid4().hex[:8]}"
    root.mkdir(parents=True)
    try:
        yield root
        written = root / relative
        if not written.is_dir():
            raise FileNotFoundError(f"nothing was written at {written} to publish")
        final.parent.mkdir(parents=True, exist_ok=True)
        if not final.exists():
            written.rename(final)
        elif overwrite:
            _replace(final, written, pathlib.Path(tempfile.mkdtemp(prefix="replaced-", dir=root)) / final.name, keep)
        else:
            raise FileExistsError(f"{final} appeared while this build ran (another build of the same dataset?)")
    finally:
        shutil.rmtree(root, ignore_errors=True)


def _replace(final: pathlib.Path, written: pathlib.Path, old: pathlib.Path, keep) -> None:
    """Move `final` to `old` and `written` to `final`, carrying the entries `keep` chooses across;
    on any failure everything goes back where it was."""
    final.rename(old)
    carried = []
    try:
        for entry in [e for e in sorted(old.iterdir()) if keep(e)] if keep is not None else []:
            if (written / entry.name).exists():
                raise FileExistsError(f"{entry} was to be kept, but the new folder has its own {entry.name}")
            entry.rename(written / entry.name)
            carried.append(entry.name)
        written.rename(final)
    except BaseException:
        for name in carried:
            (written / name).rename(old / name)
        old.rename(final)
        raise


def remove_stale(data_dir, prefix: str) -> None:
    """Delete the staging folders under `data_dir` named `prefix` + pid whose process has ended."""
    for leftover in pathlib.Path(data_dir).glob(glob.escape(prefix) + "*"):
        pid = leftover.name[len(prefix):].partition("-")[0]
        if pid.isdigit() and not _alive(int(pid)):
            shutil.rmtree(leftover, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:  # it exists, under another user
        return True
    return True
