"""Every notebook under notebooks/ runs top to bottom in a Jupyter kernel (nbclient), committed
without outputs: the walkthrough; the case study, training `tiny` itself and then opening that run
through KOSMOS_RUN; the scaling notebook on a sweep the experiment runner aggregated from fake fold
records (KOSMOS_SWEEP), whose points it must print as the runner wrote them."""

from __future__ import annotations

import json
import math
import os
import pathlib

import nbformat
import pytest
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError

from kosmos_jax.experiments import aggregate, records, spec

NOTEBOOK_DIR = pathlib.Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(NOTEBOOK_DIR.glob("*.ipynb"))
TESTED = {"walkthrough.ipynb", "case_study.ipynb", "scaling.ipynb"}


def execute(name: str, tmp_path: pathlib.Path, **env: str) -> nbformat.NotebookNode:
    """The notebook executed in a fresh kernel started in notebooks/ (as Jupyter runs it), on one CPU
    device, its temporary folders under tmp_path, with `env` added to the kernel's environment."""
    notebook = nbformat.read(NOTEBOOK_DIR / name, as_version=4)
    kernel_env = {**os.environ, "TMPDIR": str(tmp_path), "JAX_PLATFORMS": "cpu", **env}
    kernel_env.pop("XLA_FLAGS", None)  # conftest's eight fake devices: only slower to compile for
    for key in ("KOSMOS_RUN", "KOSMOS_SWEEP"):
        if key not in env:
            kernel_env.pop(key, None)
    client = NotebookClient(notebook, timeout=600, kernel_name="python3",
                            resources={"metadata": {"path": str(NOTEBOOK_DIR)}})
    client.execute(env=kernel_env)
    return notebook


def printed(notebook) -> str:
    return "".join(o.get("text", "") for c in notebook.cells if c.cell_type == "code" for o in c.get("outputs", [])
                   if o.get("output_type") == "stream")


def images(notebook) -> int:
    return sum("image/png" in o.get("data", {}) for c in notebook.cells if c.cell_type == "code"
               for o in c.get("outputs", []))


def test_there_are_notebooks_and_each_is_tested():
    assert NOTEBOOKS, "notebooks/ holds no .ipynb"
    assert {p.name for p in NOTEBOOKS} == TESTED, "a notebook without a test here (or a test of a missing one)"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_committed_without_outputs(path):
    notebook = nbformat.read(path, as_version=4)
    nbformat.validate(notebook)
    code = [c for c in notebook.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code), \
        f"{path.name} is committed with outputs; clear them"


@pytest.mark.slow  # 26 s (make test's --durations, 2026-11-28, 2 cores)
def test_walkthrough_runs(tmp_path):
    notebook = execute("walkthrough.ipynb", tmp_path)
    assert "tiny model logits" in printed(notebook) and images(notebook) == 2

# -- the case study ----------------------------------------------------------------------------------


@pytest.fixture(scope="session")
def case_study(tmp_path_factory):
    """The case study as a reader without a run executes it: it trains `tiny` in a temporary folder."""
    tmp = tmp_path_factory.mktemp("case_study")
    return execute("case_study.ipynb", tmp), tmp


@pytest.mark.slow  # 82 s with the tiny run it trains (make test's --durations, 2026-11-27, 2 cores)
@pytest.mark.xdist_group("case_study")
def test_case_study_trains_tiny_and_draws_one_grasp_per_kind(case_study):
    notebook, tmp = case_study
    text = printed(notebook)
    assert "one of each single-photo kind: non, angle, name, colour, shape" in text
    assert "5 tiles, " in text and images(notebook) == 1
    lines = [line for line in text.splitlines() if " px  theta=" in line]
    assert [line.split()[0] for line in lines] == ["non", "angle", "name", "colour", "shape"]
    (figure,) = tmp.glob("kosmos_case_study_*/fig7.png")
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.slow  # shares the case_study fixture of the test above
@pytest.mark.xdist_group("case_study")
def test_case_study_opens_the_run_named_by_kosmos_run(case_study, tmp_path):
    _, tmp = case_study
    (run,) = tmp.glob("kosmos_case_study_*/run")
    text = printed(execute("case_study.ipynb", tmp_path, KOSMOS_RUN=str(run)))
    assert f"opening the run in {run}" in text and "step 30:" in text and "5 tiles, " in text
    assert not list(tmp_path.glob("kosmos_case_study_*/run"))  # nothing trained this time

# -- the scaling notebook ------------------------------------------------------------------------------


def fake_sweep(root: pathlib.Path) -> dict:
    """Fold records of configs/experiments/data_size.py:cpu (folds 0 and 1 of 0, 1, 2) with made-up
    accuracies, aggregated by the runner's own code into results.json and data_size.json."""
    config = spec.load_config("configs/experiments/data_size.py:cpu")
    assert config.folds == "0,1,2"
    for run in (r for r in spec.runs(config) if r.fold < 2):
        data = config.arms[run.arm].overrides.data
        examples = int(data.synthetic_photos * 0.8 * data.build.augmentations) + run.fold
        accuracy = round(8.0 * math.log10(examples) - 10.0 + 3.0 * run.fold + (run.scheme == "object"), 2)
        figures = {"accuracy": accuracy, "instructions": 60}
        scores = lambda value: {"accuracy": value, "instructions": 60, "by_kind": {"non": {"accuracy": value}},
                                "by_scene": {"single": {"accuracy": value}}}
        records.write_json(run.workdir(root) / records.FOLD_FILE, {
            "fold": run.fold, "accuracy": accuracy, "by_kind": {"non": figures}, "by_scene": {"single": figures},
            "training_examples": examples, "seconds": {"total": 1.0}, "machine": {"cpu": "fake"}, "command": "pytest",
            "no_learning": {"tests": f"fold{run.fold}-{run.scheme}",
                            "scores": {"image_centre": scores(4.0 + run.fold), "gt_mean_oracle": scores(80.0)}}})
    return aggregate.write_results(config, root, "pytest fake records")


def test_scaling_plots_the_runners_points(tmp_path):
    sweep = tmp_path / "sweep"
    results = fake_sweep(sweep)
    points = json.loads((sweep / "data_size.json").read_text())["points"]
    assert len(points) == 8 * 2  # 7 arms, one on both series; image- and object-wise
    notebook = execute("scaling.ipynb", tmp_path, KOSMOS_SWEEP=str(sweep))
    text = printed(notebook)
    assert f"{sweep / 'results.json'}: experiment 'data_size'" in text and f"{len(points)} points" in text
    assert f"folds not run yet ({len(results['missing'])})" in text and len(results["missing"]) == 14
    for point in points:
        assert (f"{point['arm']:<18} {point['training_examples']:>9.0f}  {point['accuracy_mean']:6.2f} +- "
                f"{point['accuracy_std']:5.2f} ({point['n_folds']})") in text
    assert "image centre: 4.50 +- 0.50 (2)" in text and "ground-truth mean (oracle): 80.00 +- 0.00 (2)" in text
    assert images(notebook) == 1


def test_scaling_reads_data_size_json_and_names_a_missing_sweep(tmp_path):
    sweep = tmp_path / "sweep"
    fake_sweep(sweep)
    text = printed(execute("scaling.ipynb", tmp_path, KOSMOS_SWEEP=str(sweep / "data_size.json")))
    assert "the plotted points only" in text and "16 points" in text
    with pytest.raises(CellExecutionError, match="no sweep results at .*nowhere"):
        execute("scaling.ipynb", tmp_path, KOSMOS_SWEEP=str(tmp_path / "nowhere"))
