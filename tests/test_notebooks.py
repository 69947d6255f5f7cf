"""Every notebook under notebooks/ runs top to bottom (its code cells, in order, in one namespace)."""

from __future__ import annotations

import json
import pathlib
import tempfile

import pytest

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


def test_there_are_notebooks():
    assert NOTEBOOKS, "notebooks/ holds no .ipynb"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs(path, tmp_path, monkeypatch):
    notebook = json.loads(path.read_text())
    assert notebook["nbformat"] == 4
    cells = [c for c in notebook["cells"] if c["cell_type"] == "code"]
    assert all(not c.get("outputs") for c in cells), f"{path.name} is committed with outputs; clear them"
    monkeypatch.chdir(path.parent)  # as Jupyter runs it
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # what a notebook writes to a temp folder goes too
    namespace: dict = {"__name__": "__main__"}
    for number, cell in enumerate(cells):
        source = "".join(cell["source"])
        exec(compile(source, f"{path.name}[code cell {number}]", "exec"), namespace)
