"""The trainer's full step (forward, backward, clipping, AdamW) of one model size on whatever backend jax
finds, with its MFU by the model's own FLOPs: one JSON record per run.

    python benchmarks/step_mfu.py --size kosmos2 --dtype bfloat16 --scan --remat --batch 16 --length 256 [--attention fused] \
        --out results/performance/RECORD.json
    GLIBC_TUNABLES=glibc.malloc.hugetlb=1 .venv/bin/python benchmarks/step_mfu.py --size small --batch 8 --length 128

MFU is `models.flops.train_flops(...).model` (6 x the matmul work, remat's recomputation not counted)
over the step's best time and the chip's peak: the datasheet's dense figure on a known accelerator, the
measured float32 matmul peak on a CPU. The peer, measured in the same run, is a plain square matmul of
the step's dtype: the record gives its rate and our step's rate over it. XLA's count of the compiled
step stands beside the model's (it counts a scanned loop's body once). Random weights and tokens: the
step's cost does not depend on their values.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import pathlib
import sys
import time

import jax
import jax.numpy as jnp

from timing import best_time  # benchmarks/timing.py, beside this script
from train import random_batch  # benchmarks/train.py
from kosmos_jax.models import config as config_lib
from kosmos_jax.models.flops import train_flops, xla_flops
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.train.mesh import batch_sharding
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.train.state import init_train_state
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
                                attention=args.attention)
    if args.text_attention_dropout is not None:
        cfg = cfg.replace(text=dataclasses.replace(cfg.text, attention_dropout=args.text_attention_dropout))
    return cfg


def measure(cfg, batch_size: int, length: int, repeats: int) -> dict:
    mesh = make_mesh(-1, 1, 1)
    optimizer = kosmos_e.get_config("paper").optimizer
    tx, schedule = make_optimizer(optimizer, 1000)
    state = init_train_state(split_model(build(cfg))[1], tx, mesh)
    step = make_train_step(cfg, tx, schedule, mesh)
    batch = jax.device_put(random_batch(cfg, batch_size, length), batch_sharding(mesh))
    start = time.perf_counter()
    compiled = step.lower(state, batch).compile()
    compile_s = time.perf_counter() - start
    holder = {"state": state}

    def one():
        holder["state"], metrics = compiled(holder["state"], batch)  # the state is donated: carry it on
        return metrics

    step_s = best_time(one, repeats=repeats)
    stats = jax.devices()[0].memory_stats() or {}
    return {"step_s": step_s, "compile_s": compile_s, "xla_flops": xla_flops(compiled),
            "peak_bytes": stats.get("peak_bytes_in_use")}


def record(args) -> dict:
    cfg = model_config(args)
    device = jax.devices()[0]
    peer = matmul_rate(args.dtype, args.peer_size)
    run = measure(cfg, args.batch, args.length, args.repeats)
    flops = train_flops(cfg, args.batch, args.length)
    peak = DATASHEET_PEAK.get((device.device_kind, args.dtype))
    peak_source = "datasheet"
    if peak is None:
        peak, peak_source = peer, f"measured {args.dtype} matmul, {args.peer_size}^3"
    achieved = flops.model / run["step_s"] / jax.device_count()
    return {
        "device": device.device_kind, "platform": device.platform, "devices": jax.device_count(),
        "jax": jax.__version__, "size": args.size, "batch": args.batch, "length": args.length,
        "dtype": args.dtype, "remat": args.remat, "scan": args.scan, "attention": args.attention,
        "text_attention_dropout": cfg.text.attention_dropout,
        "step_s": round(run["step_s"], 5), "compile_s": round(run["compile_s"], 1),
        "tokens_per_s": round(args.batch * args.length / run["step_s"], 1),
        "model_flops": flops.model, "executed_flops": flops.executed,
        "xla_flops": run["xla_flops"] and run["xla_flops"] * jax.device_count(),
        "peak_flops_per_chip": peak, "peak_source": peak_source,
        "mfu": round(achieved / peak, 4),
        "peer_matmul_flops": round(peer), "step_rate_over_peer_matmul": round(achieved / peer, 4),
        "peak_memory_gb": run["peak_bytes"] and round(run["peak_bytes"] / 1e9, 2),
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
    parser.add_argument("--text-attention-dropout", type=float, default=None,
                        help="override the decoder's attention dropout (the size's own by default)")
    parser.add_argument("--repeats", type=int, default=5, help="timed steps; the best is kept")
    parser.add_argument("--peer-size", type=int, default=4096, help="side of the peer matmul")
    parser.add_argument("--out", type=pathlib.Path, help="also write the record to this JSON file")
    args = parser.parse_args()
    jax.config.update("jax_enable_compilation_cache", False)  # compile_s times a compile, never a cache read
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
