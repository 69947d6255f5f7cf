"""`python -m kosmos_jax.evaluate` on a baseline's workdir: a `configs/baselines.py:tiny` run the real
trainer wrote (two steps, checkpoints 1 and 2) scored through main(), as KOSMOS-E's runs are: the same
files and keys, its counts those of the fold's test views, its accuracy the trainer's; --step, --split,
a synthetic Cornell folder, the errors a user meets; and the scoring of one grasp a view itself."""

from __future__ import annotations

import contextlib
import io
import json
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest

from kosmos_jax.baselines.inputs import ViewArrays
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.evaluate.__main__ import main
from kosmos_jax.evaluate.run_scores import evaluate
from kosmos_jax.scoring.view_scores import view_results
from kosmos_jax.train.metrics_log import read_metrics

pytestmark = pytest.mark.xdist_group("evaluate_baselines")

REPO = pathlib.Path(__file__).resolve().parents[1]
STEPS = 2


@pytest.fixture(scope="session")
def workdir(tmp_path_factory):
    root = tmp_path_factory.mktemp("baseline_eval")
    workdir = root / "run"
    command = [sys.executable, "-m", "kosmos_jax.train", "--config=configs/baselines.py:tiny", f"--workdir={workdir}",
               f"--config.data.root={root / 'datasets'}", f"--config.train.steps={STEPS}",
               "--config.train.checkpoint_every=1"]
    env = dict(os.environ, GLIBC_TUNABLES="glibc.malloc.hugetlb=1",
               XLA_FLAGS="--xla_force_host_platform_device_count=1")
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return workdir


def run_cli(*args) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(map(str, args)))
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="session")
def evaluated(workdir):
    code, out, err = run_cli(f"--workdir={workdir}", "--json")
    assert code == 0, err[-3000:]
    return json.loads(out), workdir / "eval" / str(STEPS)


def test_a_baseline_run_is_scored_with_kosmos_e_s_files_and_keys(evaluated, workdir):
    results, folder = evaluated
    assert results == json.loads((folder / "results.json").read_text())
    description = json.loads((workdir / "run.json").read_text())
    assert results["step"] == STEPS and results["split"] == "test" and results["protocol"] == "honest"
    assert results["wh_policy"] == "per_gt" and results["backend"] == "exact"
    assert results["network"] == "grconvnet" and results["mode"] == "rgbd"
    assert results["instructions"] == results["examples"] == description["views"]["test"] > 0
    assert set(results["by_kind"]) == {"non"} and set(results["by_scene"]) == {"single"}
    for groups in (results["by_kind"], results["by_scene"]):
        (group,) = groups.values()
        assert group == {"accuracy": results["accuracy"], "instructions": results["instructions"],
                         "examples": results["examples"]}
    rows = [json.loads(line) for line in (folder / "answers.jsonl").read_text().splitlines()]
    assert len(rows) == results["instructions"] and all(len(r["grasp"]) == 5 for r in rows)
    assert sum(r["correct"] for r in rows) == results["correct"]
    assert results["accuracy"] == pytest.approx(100 * results["correct"] / results["instructions"], abs=1e-3)
    trainer = [r for r in read_metrics(workdir) if r.get("split") == "test"][-1]
    assert trainer["step"] == STEPS and results["accuracy"] == pytest.approx(trainer["grasp_accuracy"], abs=1e-3)
    table = (folder / "results.md").read_text()
    assert "| all |" in table and table.startswith("grconvnet (rgbd), Step 2")


def test_an_earlier_step_and_the_train_split(workdir):
    results, rows, folder = evaluate(workdir, step=1)
    assert results["step"] == 1 and folder == workdir / "eval" / "1" and len(rows) == results["instructions"]
    trained = json.loads((workdir / "run.json").read_text())["views"]["train"]
    code, out, err = run_cli(f"--workdir={workdir}", "--split=train", "--max-examples=5", "--json")
    assert code == 0, err[-3000:]
    results = json.loads(out)
    assert results["split"] == "train" and results["instructions"] == min(5, trained)
    assert (workdir / "eval" / str(STEPS) / "train" / "answers.jsonl").is_file()


def test_every_photo_of_a_cornell_folder_is_scored(workdir, tmp_path):
    folder = tmp_path / "photos"
    scenes.write_dataset(folder, photos=3, seed=11)
    code, out, err = run_cli(f"--workdir={workdir}", f"--cornell={folder}", "--json")
    assert code == 0, err[-3000:]
    results = json.loads(out)
    assert results["split"] == "cornell-photos" and results["protocol"] == "honest" and results["kinds"] == ["non"]
    assert results["photos"] == 3 and results["missing_depth"] == []
    assert results["instructions"] == results["examples"] == 3 - results["views_without_grasps"] > 0
    assert (workdir / "eval" / str(STEPS) / "cornell-photos" / "results.json").is_file()


def test_what_a_baseline_run_cannot_do_is_an_error_that_says_so(workdir, tmp_path):
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(workdir / "run.json", bare / "run.json")
    code, out, err = run_cli(f"--workdir={bare}")
    assert code == 1 and "no checkpoint" in err and not out
    code, _, err = run_cli(f"--workdir={workdir}", "--step=3")
    assert code == 1 and "no checkpoint of step 3" in err and "[1, 2]" in err
    code, _, err = run_cli(f"--workdir={workdir}", "--split=valid")
    assert code == 1 and "unknown split 'valid'" in err
    code, _, err = run_cli(f"--workdir={workdir}", "--split=validation")
    assert code == 1 and "held out no validation split" in err
    code, _, err = run_cli(f"--workdir={workdir}", f"--cornell={tmp_path}", "--kinds=colour")
    assert code == 1 and "takes no instruction" in err
    code, _, err = run_cli(f"--workdir={workdir}", f"--cornell={tmp_path / 'nothing'}")
    assert code == 1 and "does not exist" in err


def two_views() -> ViewArrays:
    grasps = np.zeros((2, 3, 5), np.float32)
    grasps[0, :2] = [[60, 80, 40, 20, 0.3], [150, 120, 30, 15, -1.0]]
    grasps[1, :1] = [[100, 100, 50, 20, 1.2]]
    mask = np.array([[True, True, False], [True, False, False]])
    return ViewArrays(np.zeros((2, 8, 8, 4), np.float32), grasps, mask, ["pcd0100", "pcd0101"], np.array([0, 3]))


@pytest.mark.parametrize("protocol", ["honest", "paper"])
def test_one_grasp_a_view_is_scored_by_the_protocol_s_metric(protocol):
    views = two_views()
    # view 0: the second ground truth's centre and angle, a jaw of another size (the protocol lends
    # w and h); view 1: its ground truth turned a quarter
    predicted = np.array([[150, 120, 5, 1, -1.0], [100, 100, 50, 20, 1.2 - np.pi / 2]], np.float32)
    results, rows = view_results(predicted, views, protocol)
    assert [r["correct"] for r in rows] == [True, False] and results["accuracy"] == 50.0
    assert [r["ground_truths"] for r in rows] == [2, 1] and rows[1]["copy"] == 3
    assert results["by_kind"]["non"]["instructions"] == 2 and results["correct"] == 1
    predicted[1, 4] = 1.2
    assert view_results(predicted, views, protocol)[0]["accuracy"] == 100.0
    with pytest.raises(ValueError, match="one \\(x, y, w, h, theta\\) a view"):
        view_results(predicted[:1], views, protocol)
