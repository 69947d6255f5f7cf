"""`python -m kosmos_jax.workdir.average`: the mean of a run's last checkpoints, or of several runs' newest,
written as an exported folder whose weights are the leafwise mean (checked against numpy's float64 mean of
the checkpoints read back), and one clear error for checkpoints that cannot be averaged."""

import json

import numpy as np
import pytest
from flax import nnx

from kosmos_jax.models import weights
from kosmos_jax.workdir import average
from kosmos_jax.workdir.run import open_run
from user_commands import run_module, train_tiny

pytestmark = pytest.mark.xdist_group("average_checkpoints")  # one worker: the tests share the trained runs


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two tiny runs of two steps from one dataset build (seeds 0 and 1), each keeping both checkpoints."""
    root = tmp_path_factory.mktemp("average_datasets")
    return [train_tiny(tmp_path_factory.mktemp(f"average_run{seed}"), root, "--config.train.checkpoint_every=1",
                       f"--config.train.seed={seed}") for seed in (0, 1)]


def flat(params) -> dict:
    return {path: np.asarray(value.get_value(), np.float64) for path, value in nnx.to_flat_state(params)}


def stored(workdir, step) -> dict:
    return flat(open_run(workdir).params(step)[1])


def written(folder) -> dict:
    return flat(nnx.state(weights.load_pretrained(folder), nnx.Param))


def assert_mean(folder, checkpoints):
    wanted = [stored(workdir, step) for workdir, step in checkpoints]
    got = written(folder)
    assert set(got) == set(wanted[0])
    for path, value in got.items():
        mean = sum(w[path] for w in wanted) / len(wanted)
        # float32 sums of two or three values: a few units of float32's resolution of the largest
        scale = max(np.abs(w[path]).max() for w in wanted)
        np.testing.assert_allclose(value, mean, rtol=0, atol=4 * np.finfo(np.float32).eps * max(scale, 1e-30),
                                   err_msg=str(path))
    assert any(not np.array_equal(wanted[0][path], wanted[1][path]) for path in got), "the checkpoints are equal"
    described = json.loads((folder / "kosmos_e.json").read_text())
    assert [(a["workdir"], a["step"]) for a in described["averaged_from"]] == [
        (str(workdir.resolve()), step) for workdir, step in checkpoints]


def test_the_tail_of_one_run_is_averaged(runs, tmp_path):
    out = tmp_path / "tail"
    done = run_module("kosmos_jax.workdir.average", f"--workdirs={runs[0]}", "--steps=2,1", f"--out={out}")
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"the mean of 2 checkpoints written to {out}" in done.stdout
    assert_mean(out, [(runs[0], 2), (runs[0], 1)])
    assert json.loads((out / "kosmos_e.json").read_text())["step"] == 2


def test_the_newest_checkpoints_of_two_runs_are_averaged(runs, tmp_path):
    out = tmp_path / "soup"
    done = run_module("kosmos_jax.workdir.average", f"--workdirs={runs[0]},{runs[1]}", f"--out={out}")
    assert done.returncode == 0, done.stderr[-3000:]
    assert_mean(out, [(runs[0], 2), (runs[1], 2)])


def test_another_model_is_refused(runs, tmp_path):
    other = train_tiny(tmp_path / "grid", tmp_path / "grid_datasets", "--config.model.connector_grid_code=3.0", steps=1)
    done = run_module("kosmos_jax.workdir.average", f"--workdirs={runs[0]},{other}", f"--out={tmp_path / 'out'}")
    assert done.returncode == 2
    assert "has another model than" in done.stderr
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("arguments, message", [
    (["--workdirs={0}"], "name at least two checkpoints"),
    (["--workdirs={0},{0}"], "a workdir is named twice"),
    (["--workdirs={0}", "--steps=2,2"], "a step is named twice"),
    (["--workdirs={0}", "--steps=1,x"], "--steps: 'x' is not a step number"),
    (["--workdirs={0}", "--steps=1,7"], "has no checkpoint of step 7"),
    (["--workdirs={0},{1}", "--out={1}"], "is not an empty folder"),
    (["--workdirs={0},missing_run"], "missing_run"),
])
def test_bad_input_gives_one_clear_error(runs, tmp_path, capsys, arguments, message):
    given = [a.format(runs[0], runs[1]) for a in arguments]
    if not any(a.startswith("--out=") for a in given):
        given.append(f"--out={tmp_path / 'out'}")
    assert average.main(given) == 2
    error = capsys.readouterr().err
    assert message in error and "Traceback" not in error, error
