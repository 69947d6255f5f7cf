"""A run exported to a self-contained folder (issue 22): a grid-code model written with the extended
config.json and read back the same; `python -m kosmos_jax.workdir.export` on a tiny trained run with
a grid code; `predict --pretrained=FOLDER` with no other flag answers as `--workdir=RUN`; training
starts from the folder, and its own export names that folder and its run; a folder without kosmos_e.json, and bad export input, give one clear error."""

import dataclasses
import json
import shutil

import cv2
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from kosmos_jax.models import weights
from kosmos_jax.models.config import EXTENDED_MODEL_TYPE, TINY
from kosmos_jax.models.kosmos2 import build, forward
from kosmos_jax.workdir.run import open_run
from user_commands import REPO, run_module, train_tiny

pytestmark = pytest.mark.xdist_group("export_folder")  # one worker: the tests share one trained run

GRID_CODE = 3.0


def params_of(model):
    return {path: np.asarray(v.get_value()) for path, v in nnx.to_flat_state(nnx.state(model, nnx.Param))}


def test_a_grid_code_model_round_trips_through_its_folder(tmp_path):
    model = build(TINY.replace(connector_grid_code=GRID_CODE), seed=3)
    weights.save_pretrained(model, tmp_path, extensions=True)
    assert json.loads((tmp_path / "config.json").read_text())["model_type"] == EXTENDED_MODEL_TYPE
    back = weights.load_pretrained(tmp_path)
    assert back.config.connector_grid_code == GRID_CODE and back.config == model.config
    original = params_of(model)
    assert set(params_of(back)) == set(original)
    for path, value in params_of(back).items():
        np.testing.assert_array_equal(value, original[path], err_msg=str(path))
    rng = np.random.default_rng(0)
    images = jnp.asarray(rng.normal(size=(2, 32, 32, 3)), jnp.float32)
    ids = jnp.asarray(rng.integers(4, TINY.text.vocab_size, (2, 8)), jnp.int32)
    mask = jnp.ones((2, 8), bool)
    image_mask = jnp.zeros((2, 8), bool).at[:, 1:1 + TINY.latent_query_num].set(True)
    model.eval(), back.eval()
    logits = np.asarray(forward(back, ids, mask, image_mask, pixels=images))
    np.testing.assert_array_equal(logits, np.asarray(forward(model, ids, mask, image_mask, pixels=images)))
    # the same weights read as KOSMOS-2 (what transformers would compute) give other logits
    plain = json.loads((tmp_path / "config.json").read_text())
    plain.update(model_type="kosmos-2")
    (tmp_path / "config.json").write_text(json.dumps(plain))
    as_kosmos_2 = weights.load_pretrained(tmp_path)
    as_kosmos_2.eval()
    assert as_kosmos_2.config.connector_grid_code == 0.0
    assert np.abs(np.asarray(forward(as_kosmos_2, ids, mask, image_mask, pixels=images)) - logits).max() > 1e-3


@pytest.fixture(scope="session")
def grid_run(tmp_path_factory):
    """A tiny run of two steps with a grid code, written by the trainer."""
    workdir, root = tmp_path_factory.mktemp("grid_run"), tmp_path_factory.mktemp("grid_datasets")
    return train_tiny(workdir, root, f"--config.model.connector_grid_code={GRID_CODE}")


@pytest.fixture(scope="session")
def exported(grid_run, tmp_path_factory):
    """The run exported by the command."""
    folder = tmp_path_factory.mktemp("exported") / "folder"
    done = run_module("kosmos_jax.workdir.export", f"--workdir={grid_run}", f"--out={folder}")
    assert done.returncode == 0, done.stderr[-3000:]
    assert f"step 2 of {grid_run} written to {folder}" in done.stdout
    return folder


@pytest.fixture(scope="module")
def photo(tmp_path_factory):
    path = tmp_path_factory.mktemp("photos") / "photo.png"
    cv2.imwrite(str(path), np.random.default_rng(0).integers(0, 256, (300, 400, 3), dtype=np.uint8))
    return path


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_the_export_holds_the_extended_config_the_tokenizer_and_the_runs_text_format(grid_run, exported):
    assert sorted(p.name for p in exported.iterdir()) == ["config.json", "kosmos_e.json", "model.safetensors",
                                                         "tokenizer.model"]
    config = json.loads((exported / "config.json").read_text())
    assert config["model_type"] == EXTENDED_MODEL_TYPE and config["kosmos_jax"] == {"connector_grid_code": GRID_CODE}
    run = open_run(grid_run)
    assert weights.read_config(exported) == run.model_config
    described = json.loads((exported / "kosmos_e.json").read_text())
    assert described["format"] == dataclasses.asdict(run.format_config)
    assert described["tokenizer"] == {"scheme": run.tokenizer.scheme, "numbers": run.tokenizer.numbers}
    assert (described["protocol"], described["step"]) == (run.protocol, 2)
    assert described["workdir"] == str(grid_run.resolve()) and len(described["grasp_size"]) == 2
    assert (described["value_window"], described["angle_window"]) == (run.config.decode.value_window,
                                                                      run.config.decode.angle_window)
    assert (exported / "tokenizer.model").read_bytes() == (grid_run / "tokenizer.model").read_bytes()
    assert described["started_from"] == []  # trained from scratch


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_predict_on_the_folder_alone_answers_as_the_run(grid_run, exported, photo):
    asked = (f"--image={photo}", "--instruction=Grasp the red mug.", "--json")
    from_run = run_module("kosmos_jax.predict", f"--workdir={grid_run}", *asked)
    from_folder = run_module("kosmos_jax.predict", f"--pretrained={exported}", *asked)
    assert from_run.returncode == 0, from_run.stderr[-3000:]
    assert from_folder.returncode == 0, from_folder.stderr[-3000:]
    assert json.loads(from_folder.stdout) == json.loads(from_run.stdout)


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_a_folder_without_kosmos_e_json_needs_the_tokenizer(exported, photo, tmp_path):
    bare = tmp_path / "bare"
    shutil.copytree(exported, bare, ignore=shutil.ignore_patterns("kosmos_e.json"))
    done = run_module("kosmos_jax.predict", f"--pretrained={bare}", f"--image={photo}")
    assert done.returncode == 2 and "Traceback" not in done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert "holds no kosmos_e.json" in last and "give --tokenizer" in last


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_the_export_command_refuses_bad_input_in_one_line(grid_run, exported, tmp_path):
    for args, says in (([f"--workdir={tmp_path / 'nowhere'}", f"--out={tmp_path / 'out'}"], "not a training run"),
                       ([f"--workdir={grid_run}", f"--out={exported}"], "not an empty folder"),
                       ([f"--workdir={grid_run}", f"--out={tmp_path / 'out'}", "--step=7"], "no checkpoint of step 7")):
        done = run_module("kosmos_jax.workdir.export", *args)
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr[-3000:]
        assert done.stderr.strip().startswith("error: ") and says in done.stderr
        assert len(done.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


@pytest.mark.slow  # 47 s (make test's --durations, 2026-11-27 14:25, 2 cores)
def test_training_starts_from_the_folder(exported, tmp_path):
    train_tiny(tmp_path / "run", tmp_path / "data", f"--config.model.connector_grid_code={GRID_CODE}",
               f"--config.init_from={exported}", f"--config.data.build.tokenizer={exported / 'tokenizer.model'}",
               "--config.data.build.tokenizer_scheme=native", steps=1)
    assert open_run(tmp_path / "run").steps() == [1]
    # its own export names the folder it started from and that folder's run
    again = tmp_path / "again"
    done = run_module("kosmos_jax.workdir.export", f"--workdir={tmp_path / 'run'}", f"--out={again}")
    assert done.returncode == 0, done.stderr[-3000:]
    assert json.loads((again / "kosmos_e.json").read_text())["started_from"] == [
        {"folder": str(exported.resolve()), "step": 2, "workdir": json.loads((exported / "kosmos_e.json").read_text())["workdir"]}]
