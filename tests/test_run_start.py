"""Fine-tuning from a pretraining run (config.init_from = its workdir, train/run_start.py): the new run
starts from exactly the parameters of the checkpoint it names, reads its token ids with that run's
tokenizer, records where it started, and refuses another model or another tokenizer."""

import dataclasses
import json
import pathlib

import jax
import numpy as np
import pytest

from kosmos_jax.experiments.spec import load_config
from kosmos_jax.models import patch_grid
from kosmos_jax.models.config import TINY
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.train import trainer
from kosmos_jax.train.run_start import check_same_model
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.workdir.export import export_pretrained
from kosmos_jax.workdir.run import open_run

pytestmark = pytest.mark.xdist_group("run_start")


@pytest.fixture(scope="session")
def pretrained(tmp_path_factory) -> pathlib.Path:
    """configs/pretrain.py:tiny trained 2 steps, a checkpoint after each."""
    config = load_config("configs/pretrain.py:tiny")
    config.data.root = str(tmp_path_factory.mktemp("pretrain_data"))
    config.train.steps, config.train.checkpoint_every, config.optimizer.warmup_steps = 2, 1, 1
    workdir = tmp_path_factory.mktemp("pretrain_run")
    trainer.train(config, workdir)
    return workdir


def finetune_config(pretrained, root, **changes):
    config = load_config("configs/kosmos_e.py:tiny")
    config.data.root = str(root)
    config.init_from = str(pretrained)
    config.update(changes)
    return config


def task_of(config):
    mesh = make_mesh(config.mesh.data, config.mesh.fsdp, config.mesh.tensor)
    tx, schedule = make_optimizer(config.optimizer, config.train.steps)
    return trainer.make_task(config, mesh, tx, schedule)


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_a_finetune_starts_from_the_named_checkpoint_with_its_tokenizer(pretrained, tmp_path):
    config = finetune_config(pretrained, tmp_path, init_step=1)
    task = task_of(config)
    state = task.init_state()
    _, expected = open_run(pretrained).params(1)
    got, want = jax.tree.leaves(state.params), jax.tree.leaves(expected)
    assert len(got) == len(want) > 0
    for a, b in zip(got, want):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # a copy: bit for bit
    _, step_2 = open_run(pretrained).params(2)
    assert any(not np.array_equal(np.asarray(a), np.asarray(b)) for a, b in zip(want, jax.tree.leaves(step_2)))
    assert task.description["init"] == {"from": str(pretrained.resolve()), "step": 1}
    build = task.description["data_identity"]["build"]
    assert build["tokenizer"]["path"] == str((pretrained / "tokenizer.model").resolve())
    assert build["tokenizer"]["sha256"] and build["tokenizer_scheme"] == "native"


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_the_newest_checkpoint_by_default(pretrained, tmp_path):
    task = task_of(finetune_config(pretrained, tmp_path))
    task.init_state()
    assert task.description["init"]["step"] == 2


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_another_model_is_refused_naming_the_difference(pretrained, tmp_path):
    config = finetune_config(pretrained, tmp_path)
    config.model.text.layers = 3
    with pytest.raises(ValueError, match="holds another model than this config's: .*layers"):
        task_of(config).init_state()


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_another_tokenizer_is_refused(pretrained, tmp_path):
    other = tmp_path / "other.model"
    other.write_bytes(b"not the run's tokenizer")
    config = finetune_config(pretrained, tmp_path)
    config.data.build.tokenizer = str(other)
    with pytest.raises(ValueError, match="is not the tokenizer of config.init_from"):
        task_of(config)


@pytest.fixture(scope="session")
def exported(pretrained, tmp_path_factory) -> pathlib.Path:
    folder = tmp_path_factory.mktemp("exported") / "folder"
    export_pretrained(pretrained, folder, step=1)
    return folder


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_a_finetune_starts_from_an_exported_folder_with_its_tokenizer(pretrained, exported, tmp_path):
    task = task_of(finetune_config(exported, tmp_path))
    state = task.init_state()
    _, expected = open_run(pretrained).params(1)
    got, want = jax.tree.leaves(state.params), jax.tree.leaves(expected)
    assert len(got) == len(want) > 0
    for a, b in zip(got, want):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))  # float32 written and read back: exact
    assert task.description["init"] == {"from": str(exported.resolve()), "step": 1, "exported": True}
    build = task.description["data_identity"]["build"]
    assert build["tokenizer"]["path"] == str((exported / "tokenizer.model").resolve())


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_an_exported_folder_refuses_a_checkpoint_step_and_other_numbers(exported, tmp_path):
    with pytest.raises(ValueError, match="init_step picks a checkpoint of a workdir only"):
        task_of(finetune_config(exported, tmp_path, init_step=1)).init_state()
    config = finetune_config(exported, tmp_path)
    recorded = config.data.build.numbers  # the tiny variants of both configs write digits
    config.data.build.numbers = "values" if recorded == "digits" else "digits"
    with pytest.raises(ValueError, match=f"numbers={recorded}"):
        task_of(config)


def test_a_variant_that_needs_a_start_says_what_to_give(tmp_path):
    config = load_config("configs/kosmos_e.py:demo_finetune")
    with pytest.raises(ValueError, match="give --config.init_from=FOLDER"):
        trainer.initial_params(config, None, None, None, {})


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_a_start_on_a_finer_grid_takes_every_weight_and_resamples_the_positions(pretrained, exported, tmp_path):
    side = TINY.vision.image_size // TINY.vision.patch_size  # the tiny variants' tower
    for start, step in ((pretrained, 2), (exported, 1)):  # a workdir's newest checkpoint; the folder holds step 1
        config = finetune_config(start, tmp_path / start.name, init_resample_positions=True)
        config.model.vision.image_size = 2 * TINY.vision.image_size
        got = jax.tree.leaves_with_path(task_of(config).init_state().params)
        want = jax.tree.leaves_with_path(open_run(pretrained).params(step)[1])
        assert [path for path, _ in got] == [path for path, _ in want]
        for (path, new), (_, old) in zip(got, want):
            if "position_embedding" in jax.tree_util.keystr(path):
                assert new.shape == (1 + (2 * side) ** 2, old.shape[1])
                np.testing.assert_array_equal(np.asarray(new), np.asarray(patch_grid.resample_positions(old, 2 * side)))
            else:
                np.testing.assert_array_equal(np.asarray(new), np.asarray(old))


@pytest.mark.slow  # make test's --durations, 2026-11-28, 2 cores: its trained run's set-up took 1-2 minutes
def test_another_image_size_is_refused_without_resampling_and_says_how(pretrained, tmp_path):
    config = finetune_config(pretrained, tmp_path)
    config.model.vision.image_size = 2 * TINY.vision.image_size
    with pytest.raises(ValueError, match="image_size .*init_resample_positions=True resamples"):
        task_of(config).init_state()


def test_resampling_allows_another_image_size_and_nothing_else():
    finer = TINY.replace(vision=dataclasses.replace(TINY.vision, image_size=2 * TINY.vision.image_size))
    check_same_model(TINY, finer, "runs/start", resample_positions=True)
    coarser_patches = finer.replace(vision=dataclasses.replace(finer.vision, patch_size=2 * TINY.vision.patch_size))
    with pytest.raises(ValueError, match="patch_size") as refused:
        check_same_model(TINY, coarser_patches, "runs/start", resample_positions=True)
    assert "init_resample_positions" not in str(refused.value)
    deeper = finer.replace(text=dataclasses.replace(TINY.text, layers=3))
    with pytest.raises(ValueError, match="layers"):
        check_same_model(TINY, deeper, "runs/start", resample_positions=True)


@pytest.mark.slow  # a tiny fine-tune's build and one step: about a minute on 2 cores
def test_a_run_trains_on_the_finer_grid_it_started_from(exported, tmp_path):
    config = finetune_config(exported, tmp_path / "data", init_resample_positions=True)
    config.model.vision.image_size = 2 * TINY.vision.image_size
    config.train.steps, config.train.checkpoint_every, config.train.grasp_eval_at_end = 2, 1, False
    config.optimizer.warmup_steps = 1
    workdir = tmp_path / "run"
    trainer.train(config, workdir)
    step, params = open_run(workdir).params(None)
    table = next(value for path, value in jax.tree.leaves_with_path(params)
                 if "position_embedding" in jax.tree_util.keystr(path))
    side = 2 * TINY.vision.image_size // TINY.vision.patch_size
    assert step == 2 and table.shape == (1 + side**2, TINY.vision.hidden_size)
    losses = [line["loss"] for line in map(json.loads, (workdir / "metrics.jsonl").read_text().splitlines())
              if "loss" in line and "split" not in line]
    assert losses and all(np.isfinite(losses))
