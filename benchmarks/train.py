"""Training benchmark, one run: the full train step of `small` against its forward+backward alone,
the data wait over a 50-step run, 1 device against 8 fake devices, checkpoint save time against
step time.

    GLIBC_TUNABLES=glibc.malloc.hugetlb=1 .venv/bin/python benchmarks/train.py [--steps 50] [--out RECORD.json]

Peers, each measured in this run: the float32 matmul peak (MFU's denominator), the forward+backward
without clipping or AdamW (what the step adds), the step on 1 device (what 8 fake devices cost),
the step (what a checkpoint save costs). FLOPs are XLA's count of each compiled program. The full
step and forward+backward are timed in turn, round after round (`--rounds`), so that a neighbour's
load falls on both alike; each figure is its best round, with the median beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import jax
import numpy as np
import optax
from flax import nnx

from timing import best_time, interleaved_times, matmul_peak  # benchmarks/timing.py, beside this script
from kosmos_jax.models import config as config_lib
from kosmos_jax.models.flops import xla_flops
from kosmos_jax.models.kosmos2 import build, split_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.train.mesh import batch_sharding
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.train.state import init_train_state
from kosmos_jax.train.step import logits as model_logits
from kosmos_jax.train.step import make_train_step
from kosmos_jax.workdir.checkpoints import Checkpoints

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "configs"))
import kosmos_e  # noqa: E402  (configs/kosmos_e.py)


def random_batch(cfg, batch: int, length: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    tokens = rng.integers(4, cfg.text.vocab_size, (batch, length)).astype(np.int32)
    image_mask = np.zeros((batch, length), bool)
    image_mask[:, 2:2 + cfg.latent_query_num] = True
    loss_mask = np.zeros((batch, length), bool)
    loss_mask[:, 2 + cfg.latent_query_num + 1:] = True
    return {"image": rng.integers(0, 256, (batch, 224, 224, 3), dtype=np.uint8), "tokens": tokens,
            "loss_mask": loss_mask, "image_mask": image_mask, "length": np.full(batch, length, np.int32),
            "grasp": np.zeros((batch, 5), np.float32), "example_index": np.arange(batch)}


def full_step(cfg, batch: dict, mesh_sizes=(1, 1, 1)) -> dict:
    """The trainer's own step (forward, backward, clipping, AdamW) on a mesh, compiled: its FLOPs, `call`
    (one step, no argument) and `state` (the state now, which each call donates and replaces)."""
    mesh = make_mesh(*mesh_sizes)
    config = kosmos_e.get_config("small")
    tx, schedule = make_optimizer(config.optimizer, 1000)
    state = init_train_state(split_model(build(cfg))[1], tx, mesh)
    step = make_train_step(cfg, tx, schedule, mesh)
    placed = jax.device_put(batch, batch_sharding(mesh))
    compiled = step.lower(state, placed).compile()
    flops = xla_flops(compiled)
    holder = {"state": state}

    def one():
        holder["state"], metrics = compiled(holder["state"], placed)  # the state is donated: carry it on
        return metrics

    return {"flops": flops, "call": one, "state": lambda: holder["state"]}


def forward_backward(cfg, batch: dict) -> dict:
    """The same loss's gradient alone, no optimiser, no clipping, dropout off: the peer of the full step."""
    model = build(cfg)
    model.eval()
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)
    arrays = jax.device_put(batch)

    def loss(params, batch):
        logits = model_logits(nnx.merge(graphdef, params, rest), batch)
        return optax.softmax_cross_entropy_with_integer_labels(logits[:, :-1], batch["tokens"][:, 1:]).mean()

    compiled = jax.jit(jax.grad(loss)).lower(params, arrays).compile()
    return {"flops": xla_flops(compiled), "call": lambda: compiled(params, arrays)}


def checkpoint_save(state, step_seconds: float) -> dict:
    with tempfile.TemporaryDirectory() as folder, Checkpoints(folder, keep=2) as checkpoints:
        times = []
        for step in (1, 2, 3):
            start = time.perf_counter()
            checkpoints.save(step, state, {"next_index": step}, {"step": step})
            blocking = time.perf_counter() - start
            checkpoints.wait()
            times.append((blocking, time.perf_counter() - start))
    blocking, total = min(t[0] for t in times), min(t[1] for t in times)
    return {"save_blocking_seconds": round(blocking, 4), "save_total_seconds": round(total, 4),
            "step_seconds": round(step_seconds, 4), "save_total_over_step": round(total / step_seconds, 3)}


def data_wait(steps: int) -> dict:
    """A real `small` training run of `steps` steps (the tiny config's synthetic data, batch 16):
    the fraction of each step spent waiting for the next batch, from its metrics.jsonl."""
    from kosmos_jax.train.metrics_log import read_metrics
    from kosmos_jax.train.trainer import train

    config = kosmos_e.get_config("small")
    tiny = kosmos_e.get_config("tiny")
    config.data = tiny.data
    with tempfile.TemporaryDirectory() as folder:
        config.data.root = str(pathlib.Path(folder) / "datasets")
        config.train.steps, config.train.batch_size, config.train.log_every = steps, 16, 1
        config.train.checkpoint_every, config.train.eval_every, config.train.eval_batches = steps, 0, 1
        config.optimizer.warmup_steps = min(config.optimizer.warmup_steps, steps // 2)
        train(config, pathlib.Path(folder) / "run")
        records = [r for r in read_metrics(pathlib.Path(folder) / "run") if "split" not in r][1:]  # step 1 compiles
    waits = np.array([r["data_wait_fraction"] for r in records])
    return {"steps_measured": len(records), "mean_data_wait_fraction": round(float(waits.mean()), 4),
            "max_data_wait_fraction": round(float(waits.max()), 4),
            "mean_step_seconds": round(float(np.mean([r["step_s"] for r in records])), 4)}


def eight_devices(batch_size: int, length: int) -> dict:
    """The full step on 8 fake CPU devices (mesh data=8), in a fresh process (XLA_FLAGS is read at start)."""
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=8")
    done = subprocess.run([sys.executable, __file__, "--only-devices", "8", "--batch", str(batch_size),
                           "--length", str(length)], env=env, capture_output=True, text=True, timeout=1800)
    if done.returncode:
        raise RuntimeError(done.stderr[-3000:])
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--length", type=int, default=128)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=8, help="rounds of the full step and forward+backward, in turn")
    parser.add_argument("--out", help="also write the report to this JSON file")
    parser.add_argument("--only-devices", type=int, default=0, help=argparse.SUPPRESS)
    args = parser.parse_args()
    cfg = config_lib.get_config("small")
    batch = random_batch(cfg, args.batch, args.length)
    if args.only_devices:
        measured = full_step(cfg, batch, (args.only_devices, 1, 1))
        print(json.dumps({"devices": jax.device_count(), "step_seconds": best_time(measured["call"], repeats=5)}))
        return
    before = matmul_peak()
    full = full_step(cfg, batch)
    alone = forward_backward(cfg, batch)
    timed = interleaved_times({"full": full["call"], "alone": alone["call"]}, args.rounds)
    full["step_seconds"], alone["step_seconds"] = timed["full"]["min"], timed["alone"]["min"]
    after = matmul_peak()
    peak = max(before["peak_gflops"], after["peak_gflops"])
    mfu = lambda run: round(run["flops"] / run["step_seconds"] / 1e9 / peak, 3)
    report = {
        "device": str(jax.devices()[0].device_kind), "size": "small", "batch": args.batch, "length": args.length,
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),
        "matmul_float32_peak_gflops": round(peak, 1),
        "timing": f"best of {args.rounds} rounds, the full step and forward+backward in turn",
        "full_step": {"seconds": round(full["step_seconds"], 4), "median_seconds": round(timed["full"]["median"], 4),
                      "rounds_seconds": timed["full"]["rounds"],
                      "flops": full["flops"], "mfu": mfu(full)},
        "forward_backward_alone": {"seconds": round(alone["step_seconds"], 4),
                                   "median_seconds": round(timed["alone"]["median"], 4),
                                   "rounds_seconds": timed["alone"]["rounds"],
                                   "flops": alone["flops"], "mfu": mfu(alone)},
        "full_step_time_over_forward_backward": round(full["step_seconds"] / alone["step_seconds"], 3),
        "checkpoint": checkpoint_save(full["state"](), full["step_seconds"]),
    }
    eight = eight_devices(args.batch, args.length)
    report["devices"] = {"one_device_step_seconds": round(full["step_seconds"], 4),
                         "eight_fake_devices_step_seconds": round(eight["step_seconds"], 4),
                         "eight_over_one": round(eight["step_seconds"] / full["step_seconds"], 3)}
    report["data_wait"] = data_wait(args.steps)
    if min(before["peak_gflops"], after["peak_gflops"]) < 0.8 * peak:
        report["warning"] = "matmul peak moved by over 20% during the run: the machine is shared, rerun"
    print(json.dumps(report, indent=2))
    if args.out:
        pathlib.Path(args.out).write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
