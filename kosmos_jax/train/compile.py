"""Compile THE train step for a device topology that need not be attached, and read its memory and FLOPs.

    python -m kosmos_jax.train.compile --config=configs/kosmos_e.py:paper --topology=v5e:2x4 [--json]
    python -m kosmos_jax.train.compile --config=configs/kosmos_e.py:tiny --topology=cpu:8 --config.mesh.fsdp=8
    python -m kosmos_jax.train.compile --config=configs/kosmos_e.py:paper --plan   # kosmos_jax/train/plan.py

TPU topologies ("v5e:2x4", "v4:2x2x1", ...) come from libtpu (`pip install -e '.[tpu]'`) with no TPU
attached: the step the trainer runs is lowered with ShapeDtypeStructs that carry their shardings on a
mesh of the topology's devices and compiled by the TPU compiler, which then tells what every chip
holds. `cpu:N` does the same on N host-platform devices. libtpu warns that it cannot determine
TPU_ACCELERATOR_TYPE and worker hostnames: harmless for compiling.

FLOPs a step are the model's own (kosmos_jax.models.flops, a function of the config), with XLA's
count of the compiled program beside them where the backend gives one.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import os
import re
import sys
import time
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import ml_collections
from absl import flags

from kosmos_jax import commands
from kosmos_jax.models import config as model_sizes
from kosmos_jax.models.flops import TrainFlops, train_flops, xla_flops
from kosmos_jax.models.kosmos2 import param_count
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.preprocess import STORED_IMAGE_SIZE
from kosmos_jax.train import plan, trainer
from kosmos_jax.train.mesh import batch_sharding
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.train.state import TrainState, abstract_train_state
from kosmos_jax.train.step import make_train_step
from kosmos_jax.workdir import model as run_model

GiB = 1 << 30


@dataclasses.dataclass(frozen=True)
class Chip:
    hbm_bytes: int
    chip_config: str  # libtpu's chip config: "megacore" makes one JAX device of a v4 chip's two cores
    host_bounds: tuple[int, int, int]  # chips a host holds, along the topology's axes, in multi-host slices
    single_host_chips: int  # slices of at most this many chips sit on one host


CHIPS = {
    "v4": Chip(32 * GiB, "megacore", (2, 2, 1), 4),
    "v5e": Chip(16 * GiB, "default", (2, 2, 1), 8),
    "v5p": Chip(95 * GiB, "default", (2, 2, 1), 4),
    "v6e": Chip(32 * GiB, "default", (2, 2, 1), 8),
}


@dataclasses.dataclass(frozen=True)
class Topology:
    name: str  # "v5e:2x4", "cpu:8"
    platform: str  # "tpu" or "cpu"
    shape: tuple[int, ...]  # chips along each axis; (N,) for cpu

    @property
    def device_count(self) -> int:
        return math.prod(self.shape)

    @property
    def chip(self) -> Chip | None:
        return CHIPS.get(self.name.split(":")[0])

    @property
    def host_bounds(self) -> tuple[int, int, int]:
        shape = (*self.shape, 1, 1)[:3]
        if self.device_count <= self.chip.single_host_chips:
            return shape
        return tuple(min(size, bound) for size, bound in zip(shape, self.chip.host_bounds))


def parse_topology(name: str) -> Topology:
    """'cpu:N' or '<chip>:AxB[xC]' with a chip of CHIPS."""
    kind, _, layout = name.partition(":")
    if kind == "cpu" and layout.isdigit() and int(layout) > 0:
        return Topology(name, "cpu", (int(layout),))
    if kind in CHIPS and re.fullmatch(r"[1-9]\d*(x[1-9]\d*){1,2}", layout):
        return Topology(name, "tpu", tuple(int(size) for size in layout.split("x")))
    raise ValueError(f"unknown topology {name!r}: expected cpu:N or <chip>:AxB[xC] with a chip of "
                     f"{sorted(CHIPS)} (e.g. v5e:2x4, v4:2x2x1)")


def topology_devices(topology: Topology) -> list[jax.Device]:
    """The topology's devices: abstract TPU devices from libtpu, or this process's CPU devices."""
    if topology.platform == "cpu":
        devices = jax.devices("cpu")
        if len(devices) != topology.device_count:
            raise ValueError(f"{topology.name} needs {topology.device_count} CPU devices, this process has "
                             f"{len(devices)}: run the command line (it sets them before jax starts) or set "
                             f"XLA_FLAGS=--xla_force_host_platform_device_count={topology.device_count}")
        return devices
    if importlib.util.find_spec("libtpu") is None:
        raise ValueError(f"{topology.name}: compiling for TPUs needs libtpu: pip install -e '.[tpu]'")
    # A compile-only client: it must not fight a running trainer (or another compile) for libtpu's lock.
    os.environ.setdefault("ALLOW_MULTIPLE_LIBTPU_LOAD", "1")
    from jax.experimental import topologies

    try:
        description = topologies.get_topology_desc(
            platform="tpu", topology_name=topology.name, chip_config_name=topology.chip.chip_config,
            chips_per_host_bounds=topology.host_bounds, num_slices=1)
    except jax.errors.JaxRuntimeError as error:
        raise ValueError(f"libtpu refuses topology {topology.name}: {str(error).splitlines()[0]}") from error
    return list(description.devices)


def hbm_bytes(topology: Topology, device: jax.Device) -> int:
    """Memory one device may use: its own figure when it is attached, else the chip's HBM (TPU) or
    this host's memory shared by the CPU devices."""
    try:
        stats = device.memory_stats() or {}
    except jax.errors.JaxRuntimeError:  # an abstract device of a topology
        stats = {}
    if "bytes_limit" in stats:
        return int(stats["bytes_limit"])
    if topology.platform == "tpu":
        return topology.chip.hbm_bytes
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // topology.device_count


def vocab_size(config: ml_collections.ConfigDict) -> int:
    """The vocabulary the trainer would take from the dataset's tokenizer, which compiling does not
    build: config.model.text.vocab_size when set, else the model size's own (KOSMOS-2's 65037)."""
    return config.model.text.get("vocab_size") or model_sizes.get_config(config.model.size).text.vocab_size


def batch_spec(config: ml_collections.ConfigDict, mesh: jax.sharding.Mesh) -> dict[str, jax.ShapeDtypeStruct]:
    """The global batch the trainer feeds (images as stored), as ShapeDtypeStructs sharded over (data, fsdp)."""
    size, length = config.train.batch_size, config.data.build.max_length
    image = STORED_IMAGE_SIZE
    sharding = batch_sharding(mesh)
    shapes = {
        "image": ((size, image, image, 3), jnp.uint8),
        "tokens": ((size, length), jnp.int32),
        "loss_mask": ((size, length), jnp.bool_),
        "image_mask": ((size, length), jnp.bool_),
        "length": ((size,), jnp.int32),
        "grasp": ((size, 5), jnp.float32),
        "example_index": ((size,), jnp.int32),
    }
    return {key: jax.ShapeDtypeStruct(shape, dtype, sharding=sharding) for key, (shape, dtype) in shapes.items()}


@dataclasses.dataclass(frozen=True)
class StepMemory:
    """Bytes per device of a compiled step, from XLA's memory analysis."""

    argument: int
    output: int
    alias: int  # outputs written into donated arguments: counted once
    temp: int
    code: int  # the program itself
    peak: int  # live at once in the TPU compiler's heap simulation (the CPU backend's leaves temporaries out)

    @property
    def total(self) -> int:
        return self.argument + self.output - self.alias + self.temp + self.code


def step_memory(compiled) -> StepMemory:
    stats = compiled.memory_analysis()
    return StepMemory(stats.argument_size_in_bytes, stats.output_size_in_bytes, stats.alias_size_in_bytes,
                      stats.temp_size_in_bytes, stats.generated_code_size_in_bytes, stats.peak_memory_in_bytes)


def sharded_bytes(tree) -> int:
    """Bytes one device holds of a tree of ShapeDtypeStructs with shardings (the most loaded device)."""
    return sum(math.prod(x.sharding.shard_shape(x.shape)) * x.dtype.itemsize for x in jax.tree.leaves(tree))


_SIZE = r"([\d.]+)([KMGT]?)\S*"
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}
# The TPU compiler's refusals: (message, what its first figure counts).
_OUT_OF_HBM = (
    (re.compile(rf"Ran out of memory in memory space hbm\. Used {_SIZE} of {_SIZE} hbm"), "total"),
    (re.compile(rf"memory required for HLO temporaries \({_SIZE}\) exceeds available HBM \({_SIZE}\)"), "temp"),
)


def hbm_overflow(message: str) -> tuple[str, int, int] | None:
    """(what the figure counts: "total" or "temp", bytes needed, bytes a chip offers) from the TPU
    compiler's out-of-memory error; None for any other error."""
    for pattern, counts in _OUT_OF_HBM:
        found = pattern.search(message)
        if found:
            needed, needed_unit, capacity, capacity_unit = found.groups()
            return counts, round(float(needed) * _UNITS[needed_unit]), round(float(capacity) * _UNITS[capacity_unit])
    return None


def memory_report(compiled, topology: Topology, hbm: int) -> dict:
    """Bytes per device of a compiled step. The TPU compiler refuses a program larger than the chip's
    usable HBM, so a TPU program that compiled fits; on CPU, the total must fit the share of RAM."""
    memory = step_memory(compiled)
    tpu = topology.platform == "tpu"
    return {
        "per_device_argument_bytes": memory.argument,
        "per_device_output_bytes": memory.output,
        "per_device_alias_bytes": memory.alias,
        "per_device_temp_bytes": memory.temp,
        "per_device_code_bytes": memory.code,
        "per_device_total_bytes": memory.total,
        "per_device_peak_bytes": memory.peak if tpu else None,
        "hbm_bytes": hbm,
        "fits": tpu or memory.total <= hbm,
    }


def refusal_report(overflow: tuple[str, int, int], argument_bytes: int) -> dict:
    """The report of a program the TPU compiler refused as too large: what it said it needed."""
    counts, needed, capacity = overflow
    if counts == "total":
        return {"per_device_total_bytes": needed, "hbm_bytes": capacity, "fits": False}
    return {"per_device_argument_bytes": argument_bytes, "per_device_temp_bytes": needed,
            "per_device_total_bytes": argument_bytes + needed, "hbm_bytes": capacity, "fits": False}


@dataclasses.dataclass(frozen=True)
class TrainerStep:
    """The jitted train step the trainer builds for a config on a mesh, and its abstract inputs."""

    step: Callable
    state: TrainState  # ShapeDtypeStructs with shardings
    batch: dict[str, jax.ShapeDtypeStruct]


def trainer_step(config: ml_collections.ConfigDict, mesh: jax.sharding.Mesh) -> TrainerStep:
    model_config = run_model.model_config(config.model, vocab_size(config))
    tx, schedule = make_optimizer(config.optimizer, config.train.steps)
    step = make_train_step(model_config, tx, schedule, mesh, microbatches=config.train.microbatches,
                           seed=config.train.seed)
    return TrainerStep(step, abstract_train_state(model_config, tx, mesh), batch_spec(config, mesh))


def model_flops(config: ml_collections.ConfigDict) -> TrainFlops:
    """The model's own FLOPs of one step of the config over the global batch (kosmos_jax.models.flops):
    the same with or without scan_layers and microbatches, and no second lowering to count them."""
    model_config = run_model.model_config(config.model, vocab_size(config))
    return train_flops(model_config, config.train.batch_size, config.data.build.max_length)


def compile_plan(config: ml_collections.ConfigDict, topology: Topology) -> dict:
    """Compile the trainer's step for `topology` and report memory per device, FLOPs and compile time.

    A TPU program too large for the chip does not compile; its report says what it needed, with
    fits False and no breakdown."""
    devices = topology_devices(topology)
    try:
        mesh = make_mesh(config.mesh.data, config.mesh.fsdp, config.mesh.tensor, devices=devices)
        trainer.check_batch_layout(config, mesh)
    except ValueError as error:
        raise ValueError(f"{topology.name}: {error}") from error
    built = trainer_step(config, mesh)
    described = {
        "topology": topology.name,
        "devices": len(devices),
        "device_kind": devices[0].device_kind,
        "mesh": dict(mesh.shape),
        "params": param_count(built.state.params),
        "batch_size": config.train.batch_size,
        "max_length": config.data.build.max_length,
        "microbatches": config.train.microbatches,
        "compute_dtype": config.model.compute_dtype,
        "remat": config.model.remat,
        "scan_layers": config.model.scan_layers,
    }
    start = time.perf_counter()
    lowered = built.step.lower(built.state, built.batch)
    lower_s = time.perf_counter() - start
    try:
        compiled = lowered.compile()
        memory = memory_report(compiled, topology, hbm_bytes(topology, devices[0]))
        counted = xla_flops(compiled)  # one device's partitioned program; every device runs the same
        counted = None if counted is None else counted * len(devices)
    except jax.errors.JaxRuntimeError as error:
        overflow = hbm_overflow(str(error))
        if overflow is None:
            raise
        memory = refusal_report(overflow, sharded_bytes((built.state, built.batch)))
        counted = None
    timing = {"lower_s": round(lower_s, 2), "compile_s": round(time.perf_counter() - start, 2)}  # lowering included
    flops = model_flops(config)
    return {**described, **memory, "model_flops": flops.as_dict(), "xla_flops": counted, **timing}


COLUMNS = ("topology", "devices", "mesh d x f x t", "remat", "scan", "batch", "args GiB", "out GiB", "temp GiB",
           "total GiB", "peak GiB", "HBM GiB", "fits", "model TFLOP", "XLA TFLOP", "compile s")


def table_row(plan: dict) -> tuple[str, ...]:
    def gib(key):
        return "-" if plan.get(key) is None else f"{plan[key] / GiB:.2f}"

    def yes(flag):
        return "yes" if flag else "no"

    def tflops(flops):
        return "-" if flops is None else f"{flops / 1e12:.4g}"

    mesh = "x".join(str(size) for size in plan["mesh"].values())
    sizes = [gib(f"per_device_{part}_bytes") for part in ("argument", "output", "temp", "total", "peak")]
    return (plan["topology"], str(plan["devices"]), mesh, yes(plan["remat"]), yes(plan["scan_layers"]),
            f"{plan['batch_size']}x{plan['max_length']}", *sizes, gib("hbm_bytes"), "yes" if plan["fits"] else "NO",
            tflops(plan["model_flops"]["model"]), tflops(plan.get("xla_flops")), f"{plan['compile_s']:.0f}")


def format_table(plans: Sequence[dict]) -> str:
    rows = [COLUMNS, *(table_row(plan) for plan in plans)]
    widths = [max(len(row[i]) for row in rows) for i in range(len(COLUMNS))]
    lines = ["  ".join(cell.rjust(width) for cell, width in zip(row, widths)) for row in rows]
    return "\n".join([lines[0], "-" * len(lines[0]), *lines[1:]])


def define_flags(flag_values: flags.FlagValues) -> None:
    commands.define_config(flag_values, "config", None, "an ml-collections config file (configs/kosmos_e.py:VARIANT)")
    flags.DEFINE_string("topology", None, "cpu:N or a TPU topology such as v5e:2x4, v4:2x2x1, v5e:16x16",
                        flag_values=flag_values)
    flags.DEFINE_bool("plan", False, "compile for every topology of kosmos_jax/train/plan.py, each with its mesh",
                      flag_values=flag_values)
    flags.DEFINE_bool("json", False, "print JSON (one object a line) instead of the table", flag_values=flag_values)
    flags.mark_flag_as_required("config", flag_values=flag_values)


def planned_runs(config: ml_collections.ConfigDict, topology_name: str | None,
                 every_planned: bool) -> list[tuple[ml_collections.ConfigDict, Topology]]:
    if every_planned and topology_name:
        raise ValueError("give --topology or --plan, not both")
    if every_planned:
        return [(plan.entry_config(config, entry), parse_topology(entry.topology)) for entry in plan.PLAN]
    if topology_name is None:
        raise ValueError("give --topology (cpu:N or a TPU topology such as v5e:2x4) or --plan")
    topology = parse_topology(topology_name)
    if topology.platform == "cpu":
        jax.config.update("jax_platforms", "cpu")  # not libtpu's client, when the tpu extra is installed
        jax.config.update("jax_num_cpu_devices", topology.device_count)
    return [(config, topology)]


def compile_command(options) -> int:
    jax.config.update("jax_enable_compilation_cache", False)  # compile_s times a compile, never a cache read
    plans = []
    try:
        for config, topology in planned_runs(options.config, options.topology, options.plan):
            plans.append(compile_plan(config, topology))
            jax.clear_caches()  # each paper-sized program holds gigabytes of host memory until dropped
            if options.json:
                print(json.dumps(plans[-1]), flush=True)
            elif options.plan:
                print(f"compiled for {topology.name} in {plans[-1]['compile_s']:.0f} s", file=sys.stderr, flush=True)
    except ValueError as error:
        print(f"compile: {error}", file=sys.stderr)
        return 1
    if not options.json:
        print(format_table(plans), flush=True)
    return 0


def main(argv=None) -> int:
    return commands.run_command(define_flags, compile_command, argv, prog="python -m kosmos_jax.train.compile",
                                doc=__doc__)


if __name__ == "__main__":
    sys.exit(main())
