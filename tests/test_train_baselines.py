"""The baselines trained by the project's trainer: `python -m kosmos_jax.train --config=configs/baselines.py:tiny`."""

from __future__ import annotations

import json
import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from kosmos_jax.train.metrics_log import read_metrics, train_losses
from kosmos_jax.workdir.checkpoints import Checkpoints

pytestmark = pytest.mark.xdist_group("train_baselines")

REPO = pathlib.Path(__file__).resolve().parents[1]
STEPS = 4
COMMON = (f"--config.optimizer.decay_steps={STEPS}",)  # runs of other lengths share every learning rate


def train(workdir, data_root, *overrides, expect: int = 0) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "kosmos_jax.train", "--config=configs/baselines.py:tiny", f"--workdir={workdir}",
               f"--config.data.root={data_root}", *COMMON, *overrides]
    env = dict(os.environ, GLIBC_TUNABLES="glibc.malloc.hugetlb=1",
               XLA_FLAGS="--xla_force_host_platform_device_count=1")
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == expect, done.stderr[-3000:]
    return done


@pytest.fixture(scope="session")
def runs(tmp_path_factory):
    """An uninterrupted run of STEPS steps, and one stopped at step 2 and resumed to STEPS."""
    root = tmp_path_factory.mktemp("baseline_runs")
    data_root = root / "datasets"
    whole, resumed = root / "whole", root / "resumed"
    train(whole, data_root, f"--config.train.steps={STEPS}")
    train(resumed, data_root, "--config.train.steps=2")
    second = train(resumed, data_root, f"--config.train.steps={STEPS}")
    return whole, resumed, second


@pytest.mark.slow  # 83 s: trains the runs fixture (make test's --durations, 2026-11-27, 2 cores)
def test_tiny_baseline_lowers_the_loss_and_scores_grasps(runs):
    whole, _, _ = runs
    losses = train_losses(whole)
    assert sorted(losses) == list(range(1, STEPS + 1))
    assert losses[STEPS] < losses[1]
    test = [r for r in read_metrics(whole) if r.get("split") == "test"]
    assert len(test) == 1 and test[0]["step"] == STEPS
    assert 0.0 <= test[0]["grasp_accuracy"] <= 100.0 and np.isfinite(test[0]["loss"])


@pytest.mark.slow  # shares the runs fixture of the test above
def test_resumed_baseline_continues_with_its_batchnorm_statistics(runs):
    whole, resumed, second = runs
    assert "resuming" in second.stderr and "from step 2" in second.stderr
    assert train_losses(resumed) == train_losses(whole)  # same batches, same updates from step 3 on
    # The test loss uses the BatchNorm running averages: equal only if step 2's were restored.
    test = {name: [r for r in read_metrics(run) if r.get("split") == "test"][-1] for name, run in
            (("whole", whole), ("resumed", resumed))}
    assert test["resumed"]["loss"] == test["whole"]["loss"]
    assert test["resumed"]["grasp_accuracy"] == test["whole"]["grasp_accuracy"]
    with Checkpoints(resumed) as checkpoints:
        assert 2 in checkpoints.all_steps() and checkpoints.latest_step() == STEPS


@pytest.mark.slow  # shares the runs fixture of the test above
def test_a_finished_baseline_run_is_found_again_and_one_of_another_seed_refused(runs):
    whole, _, _ = runs
    data_root = whole.parent / "datasets"
    assert "is finished" in train(whole, data_root, f"--config.train.steps={STEPS}").stdout
    refused = train(whole, data_root, f"--config.train.steps={STEPS}", "--config.train.seed=7", expect=1)
    assert "holds a finished run of another config: train.seed=" in refused.stderr, refused.stderr[-2000:]



@pytest.mark.slow  # one tiny run of 4 steps
def test_a_validation_split_gives_the_learning_curve_and_test_only_at_the_end(tmp_path):
    run = tmp_path / "run"
    train(run, tmp_path / "datasets", f"--config.train.steps={STEPS}", "--config.train.eval_every=2",
          "--config.data.validation_fraction=0.25")
    scored = [(r["step"], r["split"]) for r in read_metrics(run) if "split" in r]
    assert scored == [(2, "validation"), (STEPS, "validation"), (STEPS, "test")]
    description = json.loads((run / "run.json").read_text())
    assert description["data_identity"]["validation_fraction"] == 0.25 and description["views"]["validation"] > 0
    # the evaluator scores any kept checkpoint's validation views as the trainer did (a step chosen after the run)
    from kosmos_jax.evaluate.run_scores import evaluate

    for step in (2, STEPS):
        results, _, _ = evaluate(run, step=step, split="validation")
        record = next(r for r in read_metrics(run) if r.get("split") == "validation" and r["step"] == step)
        assert results["instructions"] == record["views"] == description["views"]["validation"]
        assert results["accuracy"] == pytest.approx(record["grasp_accuracy"], abs=1e-9)


@pytest.mark.slow  # 36 s (make test's --durations, 2026-11-28, 2 cores)
def test_microbatches_add_up_to_the_whole_batch_s_step():
    """GG-CNN2 (no BatchNorm, so no per-microbatch statistics): one step on 8 views makes the same
    update whole (no scan) as in 2 or 4 microbatches (the unrolled scan)."""
    import jax

    from kosmos_jax.baselines.family import BaselineConfig, make_family
    from kosmos_jax.train.baseline_task import initial_state, make_baseline_step
    from kosmos_jax.models.mesh import make_mesh
    from kosmos_jax.train.mesh import replicated
    from kosmos_jax.train.optimizer import make_optimizer

    from kosmos_jax.experiments.spec import load_config

    optimizer = load_config("configs/baselines.py:ggcnn2_d").optimizer
    family = make_family(BaselineConfig(network="ggcnn2", mode="depth"))
    mesh = make_mesh(1, 1, 1, devices=jax.devices()[:1])
    tx, schedule = make_optimizer(optimizer, 10)
    rng = np.random.default_rng(0)
    grasps = np.zeros((8, 4, 5), np.float32)
    grasps[:, :2] = np.concatenate([rng.uniform(20, 44, (8, 2, 2)), rng.uniform(8, 20, (8, 2, 2)),
                                    rng.uniform(-1.5, 1.5, (8, 2, 1))], axis=-1)
    batch = {"image": rng.uniform(-0.5, 0.5, (8, 64, 64, 1)).astype(np.float32), "grasps": grasps,
             "mask": np.repeat([[True, True, False, False]], 8, axis=0)}
    results = {}
    for microbatches in (1, 2, 4):
        state = initial_state(family, tx, 0)
        sharding = jax.tree.map(lambda _: replicated(mesh), state)
        step = make_baseline_step(family, tx, schedule, mesh, sharding, microbatches=microbatches)
        for _ in range(2):  # the first step's learning rate is 0 (warm-up)
            state, metrics = step(jax.device_put(state, sharding), batch)
        results[microbatches] = (float(metrics["loss"]), jax.tree.leaves(jax.device_get(state.params)))
    loss, params = results[1]
    for microbatches in (2, 4):
        assert results[microbatches][0] == pytest.approx(loss, rel=1e-5)
        for whole, split in zip(params, results[microbatches][1]):
            np.testing.assert_allclose(split, whole, rtol=1e-4, atol=1e-6)
