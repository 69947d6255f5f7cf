"""kosmos_jax.train.distributed: the plan read from the environment, its errors, global batches from
per-process rows, and a real run of two processes on 127.0.0.1 (two fake CPU devices each)."""

import os
import socket
import subprocess
import sys

import jax
import numpy as np
import pytest
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from kosmos_jax.train import distributed
from kosmos_jax.train.distributed import DistributedConfigError, plan_from_env

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LOCAL = {"KOSMOS_COORDINATOR": "127.0.0.1:1234", "KOSMOS_NUM_PROCESSES": "2", "KOSMOS_PROCESS_ID": "1"}
SLURM = {
    "SLURM_JOB_ID": "77",
    "SLURM_STEP_NODELIST": "node[1-2]",
    "SLURM_NTASKS": "2",
    "SLURM_PROCID": "1",
    "SLURM_LOCALID": "0",
    "SLURM_STEP_NUM_NODES": "2",
}


def test_nothing_set_is_one_process():
    plan = plan_from_env({})
    assert (plan.mode, plan.num_processes, plan.process_id) == ("single", 1, 0)


def test_local_variables():
    plan = plan_from_env(LOCAL)
    assert (plan.mode, plan.coordinator, plan.num_processes, plan.process_id) == ("explicit", "127.0.0.1:1234", 2, 1)
    assert plan.bind_address == "127.0.0.1:1234"  # loopback: listen there only
    assert plan_from_env({**LOCAL, "KOSMOS_COORDINATOR": "10.0.0.5:1234"}).bind_address is None
    assert plan_from_env({**LOCAL, "KOSMOS_COORDINATOR": "[::1]:1234"}).bind_address == "[::1]:1234"
    assert plan_from_env({**LOCAL, "KOSMOS_DISTRIBUTED_TIMEOUT": "30"}).timeout_s == 30
    one = plan_from_env({**LOCAL, "KOSMOS_NUM_PROCESSES": "1", "KOSMOS_PROCESS_ID": "0"})
    assert one.mode == "single"
    assert plan_from_env({**LOCAL, "KOSMOS_DISTRIBUTED": "off"}).mode == "single"


@pytest.mark.parametrize(
    "change, message",
    [
        ({"KOSMOS_PROCESS_ID": "one"}, "KOSMOS_PROCESS_ID='one' is not an integer"),
        ({"KOSMOS_NUM_PROCESSES": "2.0"}, "KOSMOS_NUM_PROCESSES='2.0' is not an integer"),
        ({"KOSMOS_PROCESS_ID": "2"}, r"KOSMOS_PROCESS_ID=2 must be in 0\.\.1"),
        ({"KOSMOS_PROCESS_ID": "-1"}, r"KOSMOS_PROCESS_ID=-1 must be in 0\.\.1"),
        ({"KOSMOS_NUM_PROCESSES": "0", "KOSMOS_PROCESS_ID": "0"}, "KOSMOS_NUM_PROCESSES=0 must be at least 1"),
        ({"KOSMOS_COORDINATOR": "127.0.0.1"}, "is not HOST:PORT"),
        ({"KOSMOS_COORDINATOR": "127.0.0.1:http"}, "is not HOST:PORT"),
        ({"KOSMOS_COORDINATOR": ":1234"}, "is not HOST:PORT"),
        ({"KOSMOS_COORDINATOR": "127.0.0.1:70000"}, "is not HOST:PORT"),
        ({"KOSMOS_COORDINATOR": "::1:1234"}, "IPv6 host in brackets"),
        ({"KOSMOS_COORDINATOR": ""}, "KOSMOS_COORDINATOR not set"),
        ({"KOSMOS_DISTRIBUTED": "yes"}, "KOSMOS_DISTRIBUTED='yes': expected 'auto', 'off'"),
        ({"KOSMOS_DISTRIBUTED": "auto"}, "KOSMOS_DISTRIBUTED=auto leaves the processes to jax"),
        ({"KOSMOS_DISTRIBUTED_TIMEOUT": "soon"}, "KOSMOS_DISTRIBUTED_TIMEOUT='soon' is not an integer"),
        ({"KOSMOS_DISTRIBUTED_TIMEOUT": "0"}, "must be at least 1"),
    ],
)
def test_bad_values_are_named(change, message):
    with pytest.raises(DistributedConfigError, match=message):
        plan_from_env({**LOCAL, **change})


def test_partial_local_variables_name_the_missing_ones():
    with pytest.raises(DistributedConfigError, match="KOSMOS_NUM_PROCESSES, KOSMOS_PROCESS_ID not set"):
        plan_from_env({"KOSMOS_COORDINATOR": "127.0.0.1:1234"})


def test_auto_is_left_to_jax():
    plan = plan_from_env({"KOSMOS_DISTRIBUTED": "auto"})
    assert (plan.mode, plan.num_processes, plan.process_id, plan.local_device_ids) == ("auto", None, None, None)


def test_slurm_job_step():
    plan = plan_from_env(SLURM)
    assert (plan.mode, plan.source, plan.num_processes, plan.process_id) == ("auto", "SLURM job 77", 2, 1)
    assert plan.local_device_ids is None  # no GPU on record: jax's own choice
    # one task per host on GPU hosts: all of the host's GPUs, not jax's one per SLURM_LOCALID
    assert plan_from_env({**SLURM, "CUDA_VISIBLE_DEVICES": "4,5,6,7"}).local_device_ids == (0, 1, 2, 3)
    assert plan_from_env({**SLURM, "SLURM_GPUS_ON_NODE": "8"}).local_device_ids == tuple(range(8))
    several_a_host = {**SLURM, "SLURM_STEP_NUM_NODES": "1", "CUDA_VISIBLE_DEVICES": "0"}
    assert plan_from_env(several_a_host).local_device_ids is None
    chosen = {**SLURM, "CUDA_VISIBLE_DEVICES": "0,1", "JAX_LOCAL_DEVICE_IDS": "0"}
    assert plan_from_env(chosen).local_device_ids is None
    assert plan_from_env({**SLURM, "SLURM_NTASKS": "1", "SLURM_PROCID": "0"}).mode == "single"
    # a job without a step (sbatch's own shell, salloc): one process, as jax itself would see it
    assert plan_from_env({k: v for k, v in SLURM.items() if k != "SLURM_STEP_NODELIST"}).mode == "single"
    assert plan_from_env({**SLURM, **LOCAL}).mode == "explicit"  # launch/local.sh inside an allocation
    assert plan_from_env({**SLURM, "KOSMOS_DISTRIBUTED": "off"}).mode == "single"
    with pytest.raises(DistributedConfigError, match="SLURM_PROCID='x' is not an integer"):
        plan_from_env({**SLURM, "SLURM_PROCID": "x"})


def test_single_process_initialize_is_a_no_op():
    plan = distributed.initialize_from_env({})
    assert plan.mode == "single"
    assert not jax.distributed.is_initialized()


def test_process_batch_in_one_process():
    mesh = Mesh(np.array(jax.devices()), ("data",))
    rows = 2 * jax.device_count()
    sharding = NamedSharding(mesh, PartitionSpec("data"))
    assert distributed.local_rows(sharding, rows) == slice(0, rows)  # one process holds all rows
    batch = {"tokens": np.arange(rows * 3).reshape(rows, 3), "mask": np.ones((rows, 3), bool)}
    out = distributed.process_batch(batch, sharding)
    assert out["tokens"].sharding == sharding and out["tokens"].shape == (rows, 3)
    np.testing.assert_array_equal(np.asarray(out["tokens"]), batch["tokens"])
    replicated = NamedSharding(mesh, PartitionSpec())
    per_leaf = distributed.process_batch(batch, {"tokens": sharding, "mask": replicated})
    assert per_leaf["mask"].sharding == replicated


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def clean_env(**extra: str) -> dict[str, str]:
    """os.environ without anything that would steer a launch (KOSMOS_*, SLURM_*, XLA_FLAGS), plus extra."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("KOSMOS_", "SLURM_")) and k != "XLA_FLAGS"}
    env.update(JAX_PLATFORMS="cpu", **extra)
    return env


def test_two_processes_sum_a_global_batch_on_loopback():
    """Two processes x two fake CPU devices, coordinator on 127.0.0.1: each feeds its half of the
    global batch through process_batch; the jitted sum over all four devices is the full total."""
    port = free_port()
    procs = []
    try:
        for index in range(2):
            env = clean_env(
                XLA_FLAGS="--xla_force_host_platform_device_count=2",
                KOSMOS_COORDINATOR=f"127.0.0.1:{port}",
                KOSMOS_NUM_PROCESSES="2",
                KOSMOS_PROCESS_ID=str(index),
                KOSMOS_DISTRIBUTED_TIMEOUT="60",
            )
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "kosmos_jax.train.distributed_check"],
                    cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                )
            )
        outputs = [proc.communicate(timeout=120) for proc in procs]
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    for index, (proc, (out, err)) in enumerate(zip(procs, outputs)):
        assert proc.returncode == 0, err[-3000:]
        half = f"{4 * index}:{4 * index + 4}"
        assert f"process {index}/2 (KOSMOS_* variables): 2 of 4 cpu devices, rows {half} of 8, " in out
        assert "global sum 496 (expected 496): ok" in out  # sum(range(32))
