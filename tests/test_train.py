"""The trainer end to end on `configs/kosmos_e.py:tiny`, as a user runs it (`python -m kosmos_jax.train`):
a run that lowers the loss and logs, resume after SIGTERM and kill -9 with the same losses, 8 fake
devices and 2 processes (dropout on) against 1, a checkpoint restored onto another mesh, the non-finite stop."""

import json
import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from kosmos_jax.train import batches as batches_lib
from kosmos_jax.train.metrics_log import read_metrics, train_losses
from kosmos_jax.workdir.checkpoints import Checkpoints

pytestmark = pytest.mark.xdist_group("train")  # one worker runs the module: its runs share the reference

REPO = pathlib.Path(__file__).resolve().parents[1]
STEPS = 20
# The schedule is pinned to 20 steps, so runs of other lengths share every learning rate.
COMMON = ("--config.optimizer.decay_steps=20", "--config.train.checkpoint_every=5", "--config.train.eval_every=10")


@pytest.fixture(scope="session")
def dataset_dir(tmp_path_factory):
    """The tiny config's dataset, built once (in this process) for every run of the module."""
    sys.path.insert(0, str(REPO / "configs"))
    try:
        import kosmos_e
    finally:
        sys.path.pop(0)
    config = kosmos_e.get_config("tiny")
    config.data.root = str(tmp_path_factory.mktemp("datasets"))
    return str(batches_lib.prepare(config.data).dir)


def command(workdir, dataset_dir, *overrides):
    return [sys.executable, "-m", "kosmos_jax.train", "--config=configs/kosmos_e.py:tiny", f"--workdir={workdir}",
            f"--config.data.dir={dataset_dir}", *COMMON, *overrides]


def environment(devices: int = 1) -> dict:
    env = dict(os.environ, GLIBC_TUNABLES="glibc.malloc.hugetlb=1")
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    return env


def train(workdir, dataset_dir, *overrides, devices: int = 1, expect: int = 0) -> subprocess.CompletedProcess:
    done = subprocess.run(command(workdir, dataset_dir, *overrides), cwd=REPO, env=environment(devices),
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == expect, done.stderr[-3000:]
    return done


def start(workdir, dataset_dir, *overrides) -> subprocess.Popen:
    return subprocess.Popen(command(workdir, dataset_dir, *overrides), cwd=REPO, env=environment(),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for_step(process: subprocess.Popen, workdir: pathlib.Path, step: int, timeout: float = 300) -> int:
    """Poll metrics.jsonl until a training line reaches `step`; the newest step seen."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        seen = max(train_losses(workdir), default=0)
        if seen >= step:
            return seen
        if process.poll() is not None:
            raise AssertionError(f"the run ended (exit {process.returncode}) before step {step}: {process.stderr.read()[-2000:]}")
        time.sleep(0.005)
    process.kill()
    raise AssertionError(f"no step {step} within {timeout} s")


@pytest.fixture(scope="session")
def reference(dataset_dir, tmp_path_factory):
    """An uninterrupted 20-step run on one device."""
    workdir = tmp_path_factory.mktemp("reference")
    train(workdir, dataset_dir, f"--config.train.steps={STEPS}")
    return workdir


def test_a_tiny_run_lowers_the_loss_and_logs_everything(reference, dataset_dir):
    records = read_metrics(reference)
    steps = [r for r in records if "split" not in r]
    assert [r["step"] for r in steps] == list(range(1, STEPS + 1))
    for record in steps:
        for key in ("loss", "learning_rate", "grad_norm", "examples_per_s", "tokens_per_s", "step_s", "data_wait_fraction"):
            assert np.isfinite(record[key]), (key, record)
    first, last = np.mean([r["loss"] for r in steps[:3]]), np.mean([r["loss"] for r in steps[-3:]])
    assert last < 0.8 * first, (first, last)
    evals = [r for r in records if r.get("split") == "test"]
    assert [r["step"] for r in evals] == [10, 20] and all(0 <= r["accuracy"] <= 1 for r in evals)
    assert list((reference / "tensorboard").glob("events.out.tfevents.*"))
    assert (reference / "tokenizer.model").is_file()
    assert json.loads((reference / "run.json").read_text())["config"]["variant"] == "tiny"
    assert Checkpoints(reference).all_steps() == [10, 15, 20]  # keep_checkpoints = 3
    again = train(reference, dataset_dir, f"--config.train.steps={STEPS}")
    assert "is finished" in again.stdout


def test_a_finished_run_of_another_model_or_seed_is_refused_not_reused(reference, dataset_dir):
    assert "is finished" in train(reference, dataset_dir, f"--config.train.steps={STEPS // 2}").stdout
    for change, named in (("--config.train.seed=5", "train.seed=0 (this config: 5)"),
                          ("--config.model.connector_grid_code=2.0", "model.connector_grid_code=")):
        refused = train(reference, dataset_dir, f"--config.train.steps={STEPS}", change, expect=1)
        assert f"holds a finished run of another config: {named}" in refused.stderr, refused.stderr[-2000:]


@pytest.mark.slow  # 91 to 103 s on 2 cores (make test's --durations, 2026-11-25): make test-slow
def test_sigterm_then_kill_9_resume_with_bit_identical_losses(reference, dataset_dir, tmp_path):
    workdir = tmp_path / "interrupted"
    run = start(workdir, dataset_dir, f"--config.train.steps={STEPS}")
    wait_for_step(run, workdir, 3)
    run.send_signal(signal.SIGTERM)
    assert run.wait(timeout=120) == 0, run.stderr.read()[-2000:]
    stopped = Checkpoints(workdir).latest_step()
    assert stopped is not None and stopped < STEPS  # saved where it stopped, not at the end
    run = start(workdir, dataset_dir, f"--config.train.steps={STEPS}")
    wait_for_step(run, workdir, stopped + 7)  # past the next multiple of 5: a checkpoint was being written
    run.kill()
    assert run.wait(timeout=60) == -signal.SIGKILL
    resumed = train(workdir, dataset_dir, f"--config.train.steps={STEPS}")
    assert "resuming" in resumed.stderr
    assert train_losses(workdir) == train_losses(reference)  # exact floats, every step


@pytest.mark.slow  # 67 s after the reference (make test's --durations, 2026-11-27, 2 cores)
def test_eight_devices_log_the_losses_of_one(reference, dataset_dir, tmp_path):
    train(tmp_path, dataset_dir, "--config.train.steps=5", "--config.mesh.data=2", "--config.mesh.fsdp=2",
          "--config.mesh.tensor=2", devices=8)
    losses, expected = train_losses(tmp_path), train_losses(reference)
    np.testing.assert_allclose([losses[s] for s in range(1, 6)], [expected[s] for s in range(1, 6)], rtol=1e-4)


@pytest.mark.slow  # 91 to 103 s on 2 cores (make test's --durations, 2026-11-25): make test-slow
def test_a_checkpoint_of_eight_fsdp_devices_restores_onto_one(reference, dataset_dir, tmp_path):
    train(tmp_path, dataset_dir, "--config.train.steps=5", "--config.mesh.data=1", "--config.mesh.fsdp=8", devices=8)
    resumed = train(tmp_path, dataset_dir, "--config.train.steps=10", "--config.mesh.data=1", "--config.mesh.fsdp=1")
    assert "from step 5" in resumed.stderr
    assert "schedule changes" not in resumed.stderr  # lengthened under COMMON's fixed decay: the same schedule, no note
    losses, expected = train_losses(tmp_path), train_losses(reference)
    np.testing.assert_allclose([losses[s] for s in range(6, 11)], [expected[s] for s in range(6, 11)], rtol=1e-4)


@pytest.mark.slow  # 190 s on 2 cores shared with a training run, after the reference (--durations, 2026-11-26)
def test_two_processes_log_the_losses_of_one_process_with_dropout_on(reference, dataset_dir, tmp_path):
    """PROCESSES=2 FAKE_DEVICES=2 launch/local.sh, in 2 microbatches, against the reference (1 process,
    1 device, 1 microbatch), dropout on (the tiny config's 0.1 and 0.1): each process holds every other
    example of the global batch, so a row sits elsewhere than in the reference, and in another
    microbatch; its dropout masks follow its example_index, so the losses are the same sums in
    another order. rtol 1e-4: float32 sums (eps 1.2e-7) of the same terms in another order and tree,
    ~10^2 loss tokens and ~10^3-wide reductions, compounded over 5 AdamW steps, differ by a few ulps
    (1.3e-7 measured); masks by place in the batch moved the losses by 2e-3 to 6e-3."""
    steps = 5
    assert json.loads((reference / "run.json").read_text())["model"]["text_config"]["dropout"] == 0.1
    env = dict(environment(), PROCESSES="2", FAKE_DEVICES="2", SETUP="0")
    env.pop("XLA_FLAGS")
    args = command(tmp_path, dataset_dir, f"--config.train.steps={steps}", "--config.train.microbatches=2")[4:]
    done = subprocess.run(["bash", "launch/local.sh", "train", "configs/kosmos_e.py:tiny", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=600)  # args: after "-m kosmos_jax.train --config=..."
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    two, one = train_losses(tmp_path), train_losses(reference)
    assert sorted(two) == list(range(1, steps + 1))
    np.testing.assert_allclose([two[s] for s in two], [one[s] for s in two], rtol=1e-4)


@pytest.mark.slow  # 31 s (make test's --durations, 2026-11-27 14:25, 2 cores)
def test_a_non_finite_step_stops_the_run_naming_the_step_and_its_examples(dataset_dir, tmp_path):
    done = train(tmp_path, dataset_dir, "--config.train.steps=5", "--config.optimizer.peak_lr=1e30",
                 "--config.optimizer.warmup_steps=0", "--config.train.checkpoint_every=1", expect=1)
    assert "step 2:" in done.stderr and "not finite" in done.stderr and "pcd0" in done.stderr and "(non)" in done.stderr
    assert Checkpoints(tmp_path).all_steps() == [1]  # the last good one, nothing after it



def test_a_zero_peak_rate_is_refused_before_the_workdir_is_made(dataset_dir, tmp_path):
    workdir = tmp_path / "run"
    done = train(workdir, dataset_dir, "--config.optimizer.peak_lr=0", expect=1)
    assert "optimizer.peak_lr=0.0: a learning rate must be a positive number" in done.stderr
    assert not workdir.exists()

def test_resuming_with_another_model_is_refused(reference, dataset_dir):
    done = train(reference, dataset_dir, f"--config.train.steps={STEPS + 5}", "--config.model.text.layers=3", expect=1)
    assert "another model" in done.stderr


def test_resuming_with_another_seed_is_refused(reference, dataset_dir):
    done = train(reference, dataset_dir, f"--config.train.steps={STEPS + 5}", "--config.train.seed=1", expect=1)
    assert "train.seed=0, not 1" in done.stderr
