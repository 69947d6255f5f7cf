"""The trainer's full step (forward, backward, clipping, AdamW) of one model size on whatever backend jax
finds, with its MFU by the model's own FLOPs: one JSON record per run.

    python benchmarks/step_mfu.py --size kosmos2 --dtype bfloat16 --scan --remat --batch 16 --length 256 [--attention fused] \
        [--remat-policy dots] [--no-dropout] [--dropout-mask-bits 16] [--prng unsafe_rbg] [--profile DIR] [--lock FILE] --out results/performance/RECORD.json
    GLIBC_TUNABLES=glibc.malloc.hugetlb=1 .venv/bin/python benchmarks/step_mfu.py --size small --batch 8 --length 128

MFU is `models.flops.train_flops(...).model` (6 x the matmul work, remat's recomputation not counted)
over the step's best time and the chip's peak: the datasheet's dense figure on a known accelerator, the
measured float32 matmul peak on a CPU. The peer, measured in the same run, is a plain square matmul of
the step's dtype: the record gives its rate and our step's rate over it. XLA's count of the compiled
step stands beside the model's (it counts a scanned loop's body once). Random weights and tokens: the
step's cost does not depend on their values.

With --lock FILE, several of these processes share one accelerator: each compiles its step for abstract
arrays and draws its weights on the host first (side by side), waits with --barrier DIR:N until N
names are in DIR (each process's --out stem, written after its compile; a launcher adds the name of
one that died), and holds the lock (of FILE.0) from placing its state to its last timed step, so no two
time at once and none times beside a compile. Their compile times are then times under each other's load.
--slots PATH:K lets at most K of them compile and draw weights at once (the host's memory).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import fcntl
import json
import pathlib
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from timing import best_time  # benchmarks/timing.py, beside this script
from train import random_batch  # benchmarks/train.py
from kosmos_jax.models import config as config_lib
from kosmos_jax.models.flops import train_flops, xla_flops
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.train.mesh import batch_sharding
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.train.state import abstract_train_state, init_train_state
from kosmos_jax.train.step import make_train_step

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "configs"))
import kosmos_e  # noqa: E402  (configs/kosmos_e.py)

# Dense (no sparsity) peak FLOP/s of one chip by jax's device_kind, from the vendors' datasheets.
DATASHEET_PEAK = {
    ("NVIDIA H100 80GB HBM3", "bfloat16"): 989.4e12,
    ("NVIDIA H100 80GB HBM3", "float32"): 494.7e12,  # TF32 tensor cores, XLA's default float32 matmul on GPU
    ("NVIDIA H200", "bfloat16"): 989.4e12,
    ("NVIDIA H200", "float32"): 494.7e12,
}


def matmul_rate(dtype: str, n: int) -> float:
    """FLOP/s of one n x n x n matmul in `dtype`: the peer figure."""
    a = jax.random.normal(jax.random.key(0), (n, n), dtype)
    b = jax.random.normal(jax.random.key(1), (n, n), dtype)
    return 2 * n**3 / best_time(jax.jit(jnp.matmul), a, b, repeats=5)


def model_config(args) -> config_lib.Kosmos2Config:
    cfg = config_lib.get_config(args.size, compute_dtype=args.dtype, scan_layers=args.scan, remat=args.remat,
                                remat_policy=args.remat_policy, attention=args.attention,
                                dropout_mask_bits=args.dropout_mask_bits)
    if args.text_attention_dropout is not None:
        cfg = cfg.replace(text=dataclasses.replace(cfg.text, attention_dropout=args.text_attention_dropout))
    if not args.dropout:
        cfg = cfg.replace(text=dataclasses.replace(cfg.text, dropout=0.0, attention_dropout=0.0, activation_dropout=0.0),
                          vision=dataclasses.replace(cfg.vision, attention_dropout=0.0))
    return cfg


def path_and_count(text: str) -> tuple[pathlib.Path, int]:
    """argparse type of --barrier and --slots: "PATH:N", N >= 1."""
    path, _, count = text.rpartition(":")
    if not path or not count.isdigit() or int(count) < 1:
        raise argparse.ArgumentTypeError(f"expected PATH:N with N >= 1, got {text!r}")
    return pathlib.Path(path), int(count)


def wait_at(barrier: tuple[pathlib.Path, int] | None, name: str, timeout_s: float = 900.0) -> None:
    """Add `name` to the barrier's folder and wait until it holds its N names."""
    if barrier is None:
        return
    folder, count = barrier
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).touch()
    deadline = time.monotonic() + timeout_s
    while len(list(folder.iterdir())) < count and time.monotonic() < deadline:
        time.sleep(0.5)


@contextlib.contextmanager
def one_of(slots: tuple[pathlib.Path, int] | None):
    """Inside, the lock of one of the N files PATH.0 ... PATH.N-1 (`slots` is (PATH, N)): at most N
    processes are inside at once. Nothing without slots."""
    if slots is None:
        yield
        return
    path, count = slots
    handles = [open(f"{path}.{i}", "a") for i in range(count)]
    try:
        while True:
            for handle in handles:
                try:
                    fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    continue
                try:
                    yield
                finally:
                    fcntl.flock(handle, fcntl.LOCK_UN)
                return
            time.sleep(0.5)
    finally:
        for handle in handles:
            handle.close()


def measure(cfg, args) -> dict:
    """The step compiled for abstract arrays, then, under the lock, timed on real ones (and the peer)."""
    mesh = make_mesh(-1, 1, 1)
    optimizer = kosmos_e.get_config("paper").optimizer
    tx, schedule = make_optimizer(optimizer, 1000)
    step = make_train_step(cfg, tx, schedule, mesh)
    host_batch = random_batch(cfg, args.batch, args.length)
    abstract_batch = {key: jax.ShapeDtypeStruct(value.shape, value.dtype, sharding=batch_sharding(mesh))
                      for key, value in host_batch.items()}
    with one_of(args.slots):
        start = time.perf_counter()
        compiled = step.lower(abstract_train_state(cfg, tx, mesh), abstract_batch).compile()
        compile_s = time.perf_counter() - start
        with jax.default_device(jax.devices("cpu")[0]):  # drawn on the host: no accelerator memory held while waiting
            params = jax.tree.map(np.asarray, split_model(build(cfg))[1])
    wait_at(args.barrier, args.out.stem if args.out else "step_mfu")
    with one_of(args.lock and (args.lock, 1)):
        peer = matmul_rate(args.dtype, args.peer_size)
        holder = {"state": init_train_state(params, tx, mesh)}
        batch = jax.device_put(host_batch, batch_sharding(mesh))

        def one():
            holder["state"], metrics = compiled(holder["state"], batch)  # the state is donated: carry it on
            return metrics

        step_s = best_time(one, repeats=args.repeats)
        stats = jax.devices()[0].memory_stats() or {}
        profile_error = args.profile and traced(one, args.profile)
    return {"step_s": step_s, "compile_s": compile_s, "xla_flops": xla_flops(compiled), "peer": peer,
            "peak_bytes": stats.get("peak_bytes_in_use"), "profile_error": profile_error or None}


def traced(one, folder: pathlib.Path) -> str | None:
    """One more step under jax's profiler (perfetto_trace.json.gz: every kernel's span); the error, if
    the profiler fails, instead of losing the run's figures."""
    try:
        with jax.profiler.trace(str(folder), create_perfetto_trace=True):
            jax.block_until_ready(one())
    except Exception as error:  # noqa: BLE001  (CUPTI missing or refused: the timing stands)
        return f"{type(error).__name__}: {error}"
    return None


def record(args) -> dict:
    cfg = model_config(args)
    device = jax.devices()[0]
    run = measure(cfg, args)
    peer = run["peer"]
    flops = train_flops(cfg, args.batch, args.length)
    peak = DATASHEET_PEAK.get((device.device_kind, args.dtype))
    peak_source = "datasheet"
    if peak is None:
        peak, peak_source = peer, f"measured {args.dtype} matmul, {args.peer_size}^3"
    achieved = flops.model / run["step_s"] / jax.device_count()
    return {
        "device": device.device_kind, "platform": device.platform, "devices": jax.device_count(),
        "jax": jax.__version__, "size": args.size, "batch": args.batch, "length": args.length,
        "dtype": args.dtype, "remat": args.remat, "remat_policy": cfg.remat_policy if args.remat else None,
        "scan": args.scan, "attention": args.attention, "prng": jax.config.jax_default_prng_impl,
        "dropout_mask_bits": cfg.dropout_mask_bits,
        "text_dropout": cfg.text.dropout, "text_attention_dropout": cfg.text.attention_dropout,
        "vision_attention_dropout": cfg.vision.attention_dropout,
        "step_s": round(run["step_s"], 5), "compile_s": round(run["compile_s"], 1),
        "tokens_per_s": round(args.batch * args.length / run["step_s"], 1),
        "model_flops": flops.model, "executed_flops": flops.executed,
        "xla_flops": run["xla_flops"] and run["xla_flops"] * jax.device_count(),
        "peak_flops_per_chip": peak, "peak_source": peak_source,
        "mfu": round(achieved / peak, 4),
        "peer_matmul_flops": round(peer), "step_rate_over_peer_matmul": round(achieved / peer, 4),
        "peak_memory_gb": run["peak_bytes"] and round(run["peak_bytes"] / 1e9, 2),
        "profile_error": run["profile_error"],
        "command": " ".join(["python", "benchmarks/step_mfu.py", *sys.argv[1:]]),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="small", choices=["tiny", "small", "kosmos2"])
    parser.add_argument("--dtype", default="float32", choices=["float32", "bfloat16"])
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--length", type=int, default=128)
    parser.add_argument("--scan", action=argparse.BooleanOptionalAction, default=False)
    parser.add_argument("--remat", action=argparse.BooleanOptionalAction, default=False)
    parser.add_argument("--attention", default="einsum", choices=config_lib.ATTENTION_KERNELS,
                        help="the model's attention kernel (fused: cuDNN's flash kernel on a GPU)")
    parser.add_argument("--remat-policy", default="full", choices=config_lib.REMAT_POLICIES,
                        help="under --remat, what a block keeps (dots: its dense layers' outputs)")
    parser.add_argument("--text-attention-dropout", type=float, default=None,
                        help="override the decoder's attention dropout (the size's own by default)")
    parser.add_argument("--dropout", action=argparse.BooleanOptionalAction, default=True,
                        help="--no-dropout: every dropout rate 0 (what the masks cost)")
    parser.add_argument("--dropout-mask-bits", type=int, default=32, choices=config_lib.DROPOUT_MASK_BITS,
                        help="random bits a dropout mask draws an element (Kosmos2Config.dropout_mask_bits)")
    parser.add_argument("--prng", default=None, choices=["threefry2x32", "rbg", "unsafe_rbg"],
                        help="jax's PRNG for the dropout masks (default: jax's own): what the masks cost only; the "
                             "trainer's per-example masks are tested under threefry")
    parser.add_argument("--profile", type=pathlib.Path, help="trace one more step into this folder")
    parser.add_argument("--lock", type=pathlib.Path, help="time only while holding this file's lock")
    parser.add_argument("--barrier", type=path_and_count, help="DIR:N: before timing, wait until N processes have compiled")
    parser.add_argument("--slots", type=path_and_count, help="PATH:K: at most K processes compile and draw weights at once")
    parser.add_argument("--repeats", type=int, default=5, help="timed steps; the best is kept")
    parser.add_argument("--peer-size", type=int, default=4096, help="side of the peer matmul")
    parser.add_argument("--out", type=pathlib.Path, help="also write the record to this JSON file")
    args = parser.parse_args()
    jax.config.update("jax_enable_compilation_cache", False)  # compile_s times a compile, never a cache read
    if args.prng:
        jax.config.update("jax_default_prng_impl", args.prng)
    if args.batch < 1 or args.length < 2:
        parser.error("--batch must be >= 1 and --length >= 2")
    report = record(args)
    text = json.dumps(report, indent=2)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
