"""The run layer (kosmos_jax.workdir): the parameters restored alone are exactly those of the full
train state, the optimiser's state is never read, and scoring and prediction import nothing of
kosmos_jax.train."""

import subprocess
import sys

import jax
import numpy as np
import optax

from kosmos_jax.models.config import TINY
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.train.state import abstract_train_state, init_train_state
from kosmos_jax.workdir.checkpoints import Checkpoints, checkpoint_steps, restore_params
from kosmos_jax.workdir.run import abstract_params


def saved_run(workdir, tx, step=3):
    """The train state of a fresh tiny model with `tx`'s state, saved as the trainer saves it."""
    state = init_train_state(split_model(build(TINY, seed=1))[1], tx, make_mesh(1, 1, 1, devices=jax.devices()[:1]))
    with Checkpoints(workdir, asynchronous=False) as checkpoints:
        checkpoints.save(step, state, {"position": 0}, {"step": step})
    return state


def assert_same_tree(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        assert x.dtype == y.dtype and np.array_equal(np.asarray(x), np.asarray(y))


def test_the_params_restored_alone_are_those_of_the_full_restore(tmp_path):
    tx = optax.adamw(1e-3)
    saved = saved_run(tmp_path, tx)
    mesh = make_mesh(1, 2, 1, devices=jax.devices()[:2])  # another mesh than the one saved from
    params = restore_params(tmp_path, 3, abstract_params(TINY, mesh))
    with Checkpoints(tmp_path, asynchronous=False) as checkpoints:
        full, data_state, _ = checkpoints.restore(3, abstract_train_state(TINY, tx, mesh))
    assert_same_tree(params, full.params)
    assert_same_tree(params, saved.params)
    assert data_state == {"position": 0} and checkpoint_steps(tmp_path) == [3]
    wanted = jax.tree.leaves(abstract_params(TINY, mesh))
    assert [x.sharding for x in jax.tree.leaves(params)] == [x.sharding for x in wanted]


def test_the_optimiser_state_is_not_read(tmp_path):
    # a checkpoint whose optimiser state the reader could not shape (another optimiser's: Lion's one
    # moment, not AdamW's two) still gives its parameters; only the fields asked for come back
    saved = saved_run(tmp_path, optax.lion(1e-4))
    one_device = make_mesh(1, 1, 1, devices=jax.devices()[:1])
    with Checkpoints(tmp_path, asynchronous=False) as checkpoints:
        fields = checkpoints.restore_fields(3, {"params": abstract_params(TINY, one_device)})
    assert list(fields) == ["params"]
    assert_same_tree(fields["params"], saved.params)


def test_scoring_and_prediction_import_nothing_of_the_trainer():
    code = ("import sys, kosmos_jax.predict, kosmos_jax.predict.predictor, kosmos_jax.predict.__main__, "
            "kosmos_jax.evaluate.__main__, kosmos_jax.evaluate.run_scores, kosmos_jax.evaluate.overlays, "
            "kosmos_jax.scoring.model_scores, "
            "kosmos_jax.workdir.run, kosmos_jax.workdir.export, kosmos_jax.workdir.pretrained; "
            "print(sorted(m for m in sys.modules if m.startswith('kosmos_jax.train')))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.strip() == "[]"
