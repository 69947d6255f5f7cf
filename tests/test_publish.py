"""publish.staged: a folder appears whole or not at all, replaced folders keep what is asked for
and come back when the swap fails, killed writers' staging folders are cleared."""

import os
import pathlib
import socket

import pytest

from kosmos_jax import publish


def contents(root: pathlib.Path) -> dict:
    return {str(p.relative_to(root)): p.read_text() for p in sorted(root.rglob("*")) if p.is_file()}


def write(folder: pathlib.Path, files: dict) -> None:
    for name, text in files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_text(text)


def test_a_folder_is_published_whole_and_its_staging_folder_goes(tmp_path):
    with publish.staged(tmp_path, "set/v1") as root:
        assert root.parent == tmp_path
        assert root.name.startswith(f".staging-set+v1-{socket.gethostname()}-{os.getpid()}-")
        write(root / "set/v1", {"a.txt": "new"})
        assert not (tmp_path / "set").exists()  # nothing under the final name before the end
    assert contents(tmp_path) == {"set/v1/a.txt": "new"}


def test_a_failed_writer_leaves_nothing_and_an_existing_folder_needs_overwrite(tmp_path):
    with pytest.raises(RuntimeError, match="disk full"):
        with publish.staged(tmp_path, "out") as root:
            write(root / "out", {"a.txt": "half"})
            raise RuntimeError("disk full")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(FileNotFoundError, match="nothing was written"):
        with publish.staged(tmp_path, "out"):
            pass
    write(tmp_path / "out", {"a.txt": "old"})
    with pytest.raises(FileExistsError, match="appeared while this build ran"):
        with publish.staged(tmp_path, "out") as root:
            write(root / "out", {"a.txt": "new"})
    assert contents(tmp_path) == {"out/a.txt": "old"}


def test_overwrite_replaces_and_keep_carries_chosen_entries_across(tmp_path):
    write(tmp_path / "out", {"data.bin": "old", "notes.txt": "mine", "mine/plan.txt": "also mine"})
    with publish.staged(tmp_path, "out", True, keep=lambda entry: entry.name in ("notes.txt", "mine")) as root:
        write(root / "out", {"data.bin": "new"})
    assert contents(tmp_path) == {"out/data.bin": "new", "out/notes.txt": "mine", "out/mine/plan.txt": "also mine"}
    with publish.staged(tmp_path, "out", overwrite=True) as root:  # no keep: nothing carried
        write(root / "out", {"data.bin": "newer"})
    assert contents(tmp_path) == {"out/data.bin": "newer"}


def test_a_kept_entry_never_replaces_a_new_one(tmp_path):
    write(tmp_path / "out", {"data.bin": "old", "notes.txt": "mine"})
    with pytest.raises(FileExistsError, match="new folder has its own data.bin"):
        with publish.staged(tmp_path, "out", True, keep=lambda entry: True) as root:
            write(root / "out", {"data.bin": "new"})
    assert contents(tmp_path) == {"out/data.bin": "old", "out/notes.txt": "mine"}


def test_a_failed_final_rename_puts_the_old_folder_back(tmp_path, monkeypatch):
    write(tmp_path / "out", {"data.bin": "old", "notes.txt": "mine"})
    rename = pathlib.Path.rename

    def failing(self, target):
        if pathlib.Path(target) == tmp_path / "out" and self.parent.name.startswith(".staging-"):
            raise OSError("rename refused")  # only the new folder's move into place
        return rename(self, target)

    monkeypatch.setattr(pathlib.Path, "rename", failing)
    with pytest.raises(OSError, match="rename refused"):
        with publish.staged(tmp_path, "out", True, keep=lambda entry: entry.name == "notes.txt") as root:
            write(root / "out", {"data.bin": "new"})
    assert contents(tmp_path) == {"out/data.bin": "old", "out/notes.txt": "mine"}
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_killed_writers_staging_folders_are_removed_by_the_next_writer(tmp_path, dead_pid):
    prefix = publish.staging_prefix("out")
    assert prefix == f".staging-out-{socket.gethostname()}-"
    dead, live = tmp_path / f"{prefix}{dead_pid}-0a1b2c3d", tmp_path / f"{prefix}{os.getpid()}-4e5f6a7b"
    other = tmp_path / f"{publish.staging_prefix('other')}{dead_pid}-0a1b2c3d"  # another destination's
    elsewhere = tmp_path / f".staging-out-other-machine-{dead_pid}-0a1b2c3d"  # another host's
    for folder in (dead, live, other, elsewhere):
        write(folder / "out", {"a.txt": "half"})
    with publish.staged(tmp_path, "out") as root:
        write(root / "out", {"a.txt": "new"})
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, other.name, elsewhere.name, "out"])
