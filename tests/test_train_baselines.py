"""The baselines trained by the project's trainer: `python -m kosmos_jax.train --config=configs/baselines.py:tiny`."""

from __future__ import annotations

import os
import pathlib
import subprocess
import sys

import numpy as np
import pytest

from kosmos_jax.train.checkpoint import Checkpoints
from kosmos_jax.train.metrics_log import read_metrics, train_losses

pytestmark = pytest.mark.xdist_group("train_baselines")

REPO = pathlib.Path(__file__).resolve().parents[1]
STEPS = 4
COMMON = (f"--config.optimizer.decay_steps={STEPS}",)  # runs of other lengths share every learning rate


def train(workdir, data_root, *overrides) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "kosmos_jax.train", "--config=configs/baselines.py:tiny", f"--workdir={workdir}",
               f"--config.data.root={data_root}", *COMMON, *overrides]
    env = dict(os.environ, GLIBC_TUNABLES="glibc.malloc.hugetlb=1",
               XLA_FLAGS="--xla_force_host_platform_device_count=1")
    done = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return done


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """An uninterrupted run of STEPS steps, and one stopped at step 2 and resumed to STEPS."""
    root = tmp_path_factory.mktemp("baseline_runs")
    data_root = root / "datasets"
    whole, resumed = root / "whole", root / "resumed"
    train(whole, data_root, f"--config.train.steps={STEPS}")
    train(resumed, data_root, "--config.train.steps=2")
    second = train(resumed, data_root, f"--config.train.steps={STEPS}")
    return whole, resumed, second


def test_tiny_baseline_lowers_the_loss_and_scores_grasps(runs):
    whole, _, _ = runs
    losses = train_losses(whole)
    assert sorted(losses) == list(range(1, STEPS + 1))
    assert losses[STEPS] < losses[1]
    test = [r for r in read_metrics(whole) if r.get("split") == "test"]
    assert len(test) == 1 and test[0]["step"] == STEPS
    assert 0.0 <= test[0]["grasp_accuracy"] <= 100.0 and np.isfinite(test[0]["loss"])


def test_resumed_baseline_continues_with_its_batchnorm_statistics(runs):
    whole, resumed, second = runs
    assert "resuming" in second.stderr and "from step 2" in second.stderr
    assert train_losses(resumed) == train_losses(whole)  # same batches, same updates from step 3 on
    # The test loss uses the BatchNorm running averages: equal only if step 2's were restored.
    test = {name: [r for r in read_metrics(run) if r.get("split") == "test"][-1] for name, run in
            (("whole", whole), ("resumed", resumed))}
    assert test["resumed"]["loss"] == test["whole"]["loss"]
    assert test["resumed"]["grasp_accuracy"] == test["whole"]["grasp_accuracy"]
    checkpoints = Checkpoints(resumed)
    try:
        assert 2 in checkpoints.all_steps() and checkpoints.latest_step() == STEPS
    finally:
        checkpoints.close()
