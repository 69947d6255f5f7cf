"""Many processes, many hosts: `jax.distributed` set up from the environment, and global batches
built from the part of them each process holds.

A trainer calls `initialize_from_env()` first, before any other use of jax. What it does depends on
the environment (`plan_from_env` reads it, without side effects):

- `KOSMOS_COORDINATOR=HOST:PORT`, `KOSMOS_NUM_PROCESSES=N`, `KOSMOS_PROCESS_ID=I` (all three;
  `PROCESSES=N launch/local.sh` sets them, or set them by hand on machines of your own):
  `jax.distributed.initialize(HOST:PORT, N, I)`, with no cluster auto-detection. A loopback
  coordinator (127.0.0.1, localhost, ::1) binds to that address only. They win over SLURM's.
- a SLURM job step of several tasks (`SLURM_JOB_ID`, `SLURM_STEP_NODELIST`, `SLURM_NTASKS` > 1,
  `SLURM_PROCID`, `SLURM_LOCALID`, as `srun` sets them; launch/slurm.sbatch):
  `jax.distributed.initialize()` with no arguments; jax reads those variables itself
  (jax/_src/clusters/slurm_cluster.py) and takes the job's first node as coordinator. jax would
  then give each task one GPU (its SLURM_LOCALID); with one task per host (as many tasks as
  nodes) each task gets all of its host's GPUs instead (CUDA_VISIBLE_DEVICES, else
  SLURM_GPUS_ON_NODE), unless JAX_LOCAL_DEVICE_IDS says which.
- `KOSMOS_DISTRIBUTED=auto` (launch/tpu_vm.sh sets it on every worker of a TPU VM slice; it also
  suits any cluster jax detects on its own: Open MPI, Kubernetes, GKE TPUs):
  `jax.distributed.initialize()` with no arguments; on a TPU VM jax finds the slice's workers from
  the TPU metadata server.
- `KOSMOS_DISTRIBUTED=off`, or none of the above, or a single process: nothing (one process and its
  local devices).

`KOSMOS_DISTRIBUTED_TIMEOUT=SECONDS` bounds the wait for the other processes (jax's 300 otherwise).
Several processes exchange CPU arrays through gloo (`jax_cpu_collectives_implementation`), unless
`JAX_CPU_COLLECTIVES_IMPLEMENTATION` says otherwise.

`process_batch(local_batch, sharding)` turns each process's rows of a global batch into global
`jax.Array`s; `local_rows(sharding, global_rows)` says which rows those are.
`python -m kosmos_jax.train.distributed_check` checks the whole set-up end to end.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Mapping
from typing import Any

COORDINATOR = "KOSMOS_COORDINATOR"
NUM_PROCESSES = "KOSMOS_NUM_PROCESSES"
PROCESS_ID = "KOSMOS_PROCESS_ID"
MODE = "KOSMOS_DISTRIBUTED"
TIMEOUT = "KOSMOS_DISTRIBUTED_TIMEOUT"
LOCAL_VARS = (COORDINATOR, NUM_PROCESSES, PROCESS_ID)
# What jax's SlurmCluster needs to detect a job step (srun sets them all).
SLURM_VARS = ("SLURM_JOB_ID", "SLURM_STEP_NODELIST", "SLURM_NTASKS", "SLURM_PROCID", "SLURM_LOCALID")
LOOPBACK = ("127.0.0.1", "localhost", "::1")
DEFAULT_TIMEOUT_S = 300


class DistributedConfigError(ValueError):
    """The environment asks for a distributed run in a way that cannot work."""


@dataclasses.dataclass(frozen=True)
class Plan:
    """What `initialize_from_env` does. mode: "single" (nothing), "explicit" (the KOSMOS_*
    coordinator, count and id) or "auto" (jax.distributed.initialize() with no arguments: SLURM,
    TPU VM, ...). num_processes and process_id are known ahead only for "explicit" and "single"."""

    mode: str
    source: str
    coordinator: str | None = None
    num_processes: int | None = 1
    process_id: int | None = 0
    timeout_s: int = DEFAULT_TIMEOUT_S
    local_device_ids: tuple[int, ...] | None = None

    @property
    def bind_address(self) -> str | None:
        """Where the coordinator listens: the coordinator itself when it is a loopback address
        (nothing outside this machine can reach it), else jax's default (all interfaces)."""
        if self.coordinator is None:
            return None
        host = self.coordinator.rsplit(":", 1)[0].strip("[]")
        return self.coordinator if host in LOOPBACK else None


def _integer(env: Mapping[str, str], name: str) -> int:
    value = env[name].strip()
    try:
        return int(value)
    except ValueError:
        raise DistributedConfigError(f"{name}={env[name]!r} is not an integer") from None


def parse_coordinator(value: str, name: str = COORDINATOR) -> str:
    """HOST:PORT (an IPv6 host in brackets: [::1]:1234), port in 1..65535; returned stripped."""
    value = value.strip()
    host, sep, port = value.rpartition(":")
    if not sep or host in ("", "[]") or not port.isdigit() or not 0 < int(port) < 65536:
        raise DistributedConfigError(f"{name}={value!r} is not HOST:PORT (e.g. 127.0.0.1:12345)")
    if ":" in host and not (host.startswith("[") and host.endswith("]")):
        raise DistributedConfigError(f"{name}={value!r}: write an IPv6 host in brackets, e.g. [::1]:12345")
    return value


def plan_from_env(env: Mapping[str, str] | None = None) -> Plan:
    """What the environment (os.environ by default) asks for; raises DistributedConfigError with
    the variable's name when a value cannot work."""
    env = os.environ if env is None else env
    timeout = DEFAULT_TIMEOUT_S
    if env.get(TIMEOUT, "").strip():
        timeout = _integer(env, TIMEOUT)
        if timeout < 1:
            raise DistributedConfigError(f"{TIMEOUT}={env[TIMEOUT]!r} must be at least 1 (seconds)")
    mode = env.get(MODE, "").strip().lower()
    if mode not in ("", "auto", "off"):
        raise DistributedConfigError(f"{MODE}={env[MODE]!r}: expected 'auto', 'off' or nothing")
    if mode == "off":
        return Plan("single", f"{MODE}=off", timeout_s=timeout)
    given = [name for name in LOCAL_VARS if env.get(name, "").strip()]
    if mode == "auto":
        if given:
            raise DistributedConfigError(f"{MODE}=auto leaves the processes to jax; unset {', '.join(given)}")
        return Plan("auto", f"{MODE}=auto", num_processes=None, process_id=None, timeout_s=timeout)
    if given:
        missing = [name for name in LOCAL_VARS if name not in given]
        if missing:
            raise DistributedConfigError(f"{', '.join(LOCAL_VARS)} go together; {', '.join(missing)} not set")
        coordinator = parse_coordinator(env[COORDINATOR])
        count, index = _integer(env, NUM_PROCESSES), _integer(env, PROCESS_ID)
        if count < 1:
            raise DistributedConfigError(f"{NUM_PROCESSES}={count} must be at least 1")
        if not 0 <= index < count:
            raise DistributedConfigError(f"{PROCESS_ID}={index} must be in 0..{count - 1} ({NUM_PROCESSES}={count})")
        if count == 1:
            return Plan("single", f"{NUM_PROCESSES}=1", timeout_s=timeout)
        return Plan("explicit", "KOSMOS_* variables", coordinator, count, index, timeout)
    if all(env.get(name, "").strip() for name in SLURM_VARS):
        count, index = _integer(env, "SLURM_NTASKS"), _integer(env, "SLURM_PROCID")
        if count > 1:
            devices = None
            if env.get("SLURM_STEP_NUM_NODES", "").strip() == str(count) and not env.get("JAX_LOCAL_DEVICE_IDS"):
                devices = _host_gpus(env)
            return Plan("auto", f"SLURM job {env['SLURM_JOB_ID']}", None, count, index, timeout, devices)
        return Plan("single", "SLURM_NTASKS=1", timeout_s=timeout)
    return Plan("single", "no distributed variables", timeout_s=timeout)


def _host_gpus(env: Mapping[str, str]) -> tuple[int, ...] | None:
    """All the GPUs this host shows a task, as jax's visible-device indices; None when unknown."""
    visible = env.get("CUDA_VISIBLE_DEVICES", "").strip()
    if visible:
        return tuple(range(len(visible.split(","))))
    gpus = env.get("SLURM_GPUS_ON_NODE", "").strip()
    return tuple(range(int(gpus))) if gpus.isdigit() and int(gpus) > 0 else None


def initialize_from_env(env: Mapping[str, str] | None = None) -> Plan:
    """Start jax's distributed system as the environment (os.environ by default) asks; see the
    module's docstring. Call it before any other use of jax. Returns the plan it followed; a
    second call (already initialized) does nothing."""
    plan = plan_from_env(env)
    if plan.mode == "single":
        return plan
    import jax

    if jax.distributed.is_initialized():
        return plan
    if not os.environ.get("JAX_CPU_COLLECTIVES_IMPLEMENTATION"):
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    if plan.mode == "explicit":
        jax.distributed.initialize(
            coordinator_address=plan.coordinator,
            num_processes=plan.num_processes,
            process_id=plan.process_id,
            cluster_detection_method="deactivate",
            initialization_timeout=plan.timeout_s,
            coordinator_bind_address=plan.bind_address,
        )
    else:
        devices = None if plan.local_device_ids is None else list(plan.local_device_ids)
        jax.distributed.initialize(local_device_ids=devices, initialization_timeout=plan.timeout_s)
    return plan


def local_rows(sharding: Any, global_rows: int) -> slice:
    """The rows of a global batch of `global_rows` rows (leading axis) that this process holds
    under `sharding`, as one contiguous slice; an error when they are not contiguous (a mesh whose
    batch axes interleave the processes)."""
    indices = sharding.addressable_devices_indices_map((global_rows,))
    spans = sorted({index[0].indices(global_rows)[:2] for index in indices.values()})
    start, stop = spans[0]
    for lo, hi in spans[1:]:
        if lo > stop:
            raise ValueError(f"this process's rows of the batch are not contiguous: {spans}")
        stop = max(stop, hi)
    return slice(start, stop)


def process_batch(local_batch: Any, sharding: Any) -> Any:
    """Global `jax.Array`s from this process's rows of each leaf of a batch (a dict or any tree of
    arrays): `jax.make_array_from_process_local_data` for each leaf. `sharding` is one Sharding
    for every leaf or a tree of them matching the batch; each process passes the rows
    `local_rows` names, in order, and the global leading size is the sum over processes."""
    import jax
    import numpy as np

    def one(part, leaf_sharding):
        return jax.make_array_from_process_local_data(leaf_sharding, np.asarray(part))

    if isinstance(sharding, jax.sharding.Sharding):
        return jax.tree.map(lambda part: one(part, sharding), local_batch)
    return jax.tree.map(one, local_batch, sharding)
