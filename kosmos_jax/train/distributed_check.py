"""Does my multi-process, multi-host set-up work? A smoke check with the trainer's own set-up.

    python -m kosmos_jax.train.distributed_check                  # one process and its devices
    PROCESSES=2 FAKE_DEVICES=2 launch/local.sh train.distributed_check configs/demo.py:tiny
    MODULE=train.distributed_check sbatch --nodes=2 launch/slurm.sbatch CONFIG WORKDIR
    launch/tpu_vm.sh --name=NAME --zone=ZONE train.distributed_check CONFIG

Each process starts jax's distributed system from the environment as the trainer does
(`distributed.initialize_from_env`), puts its own rows of a global batch on a mesh of all devices
of all processes (`distributed.process_batch`), and sums the whole batch in one jitted program (an
all-reduce across processes). Each process prints one line such as

    process 1/2 (KOSMOS_* variables): 2 of 4 cpu devices, rows 8:16 of 16, global sum 2016 (expected 2016): ok

and exits 1 when the sum or its process index is wrong. `--config` and `--workdir` are accepted and
ignored, so the trainer's command line works unchanged.
"""

from __future__ import annotations

import sys

from absl import flags

from kosmos_jax import commands
from kosmos_jax.train import distributed

COLUMNS = 4
ROWS_PER_DEVICE = 2


def check() -> bool:
    """Run the check in this process; print its line; True when it passed."""
    plan = distributed.initialize_from_env()
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    mesh = Mesh(np.array(jax.devices()), ("data",))
    rows = ROWS_PER_DEVICE * jax.device_count()
    full = np.arange(rows * COLUMNS, dtype=np.int32).reshape(rows, COLUMNS)
    mine = distributed.local_rows(NamedSharding(mesh, PartitionSpec("data")), rows)
    batch = distributed.process_batch({"x": full[mine]}, NamedSharding(mesh, PartitionSpec("data")))
    total = jax.jit(jnp.sum, out_shardings=NamedSharding(mesh, PartitionSpec()))(batch["x"])
    got, expected = int(total.addressable_data(0)), int(full.sum())
    index, count = jax.process_index(), jax.process_count()
    ok = got == expected and (plan.process_id is None or plan.process_id == index)
    print(
        f"process {index}/{count} ({plan.source}): {jax.local_device_count()} of {jax.device_count()} "
        f"{jax.devices()[0].platform} devices, rows {mine.start}:{mine.stop} of {rows}, "
        f"global sum {got} (expected {expected}): {'ok' if ok else 'FAILED'}",
        flush=True,
    )
    return ok


def define_flags(flag_values: flags.FlagValues) -> None:
    commands.define_config(flag_values, "config", None, "accepted and ignored (the trainer's command line works)")
    flags.DEFINE_string("workdir", None, "accepted and ignored", flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_flags, lambda options: 0 if check() else 1, argv,
                                prog="python -m kosmos_jax.train.distributed_check", doc=__doc__)


if __name__ == "__main__":
    sys.exit(main())
