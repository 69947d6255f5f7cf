"""Model benchmark, one run: float32 matmul peak, forward+backward MFU of the `small` config, decoding speed.

    make bench                     # all benchmarks, with the Makefile's GLIBC_TUNABLES
    GLIBC_TUNABLES=glibc.malloc.hugetlb=1 .venv/bin/python benchmarks/model.py [--batch 8 --length 128]

Without the glibc tunable, the kernel faults in the step's fresh buffers 4 KiB at a time on every
step; `minor_page_faults_per_step` shows it (see the Makefile).

MFU FLOPs are counted twice: by XLA's cost analysis of the compiled step and by the model's own
count (kosmos_jax.models.flops: matmuls and attention products only). Both are printed.
"""

from __future__ import annotations

import argparse
import json
import os
import resource

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx

from timing import best_time, matmul_peak  # benchmarks/timing.py, beside this script
from kosmos_jax.models import config as config_lib
from kosmos_jax.models import generation
from kosmos_jax.models.flops import train_flops, xla_flops
from kosmos_jax.models.kosmos2 import build


def inputs(cfg, batch, length, seed=0):
    rng = np.random.default_rng(seed)
    ids = rng.integers(4, cfg.text.vocab_size, (batch, length)).astype(np.int32)
    image_mask = np.zeros((batch, length), bool)
    image_mask[:, 2:2 + cfg.latent_query_num] = True
    size = cfg.vision.image_size
    pixels = rng.normal(size=(batch, size, size, 3)).astype(np.float32)
    return jnp.asarray(ids), jnp.ones((batch, length), bool), jnp.asarray(image_mask), jnp.asarray(pixels)


def train_step_speed(cfg, batch, length) -> dict:
    model = build(cfg)
    model.eval()  # dropout off: measure the arithmetic, not the RNG
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)
    ids, mask, image_mask, pixels = inputs(cfg, batch, length)

    def loss_fn(params, ids, mask, image_mask, pixels):
        logits = nnx.merge(graphdef, params, rest)(ids, mask, image_mask, pixels=pixels)
        return optax.softmax_cross_entropy_with_integer_labels(logits[:, :-1], ids[:, 1:]).mean()

    step = jax.jit(jax.value_and_grad(loss_fn))
    compiled = step.lower(params, ids, mask, image_mask, pixels).compile()
    counted = xla_flops(compiled)
    counted = float("nan") if counted is None else counted
    seconds = best_time(compiled, params, ids, mask, image_mask, pixels, repeats=3)
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    jax.block_until_ready(compiled(params, ids, mask, image_mask, pixels))
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
    by_formula = train_flops(cfg, batch, length).model
    return {
        "batch": batch, "length": length, "step_seconds": round(seconds, 4),
        "flops_xla": counted, "flops_formula": by_formula,
        "gflops_per_s_xla": round(counted / seconds / 1e9, 1),
        "gflops_per_s_formula": round(by_formula / seconds / 1e9, 1),
        "minor_page_faults_per_step": faults,
    }


def decoding_speed(cfg, batch, prompt, new_tokens) -> dict:
    model = build(cfg, seed=1)
    model.eval()
    ids, mask, image_mask, pixels = inputs(cfg, batch, prompt)
    embeds = jax.jit(lambda p: nnx.merge(*nnx.split(model)).image_embeds(p))(pixels)
    out = {}
    for use_cache in (True, False):
        seconds = best_time(lambda: generation.generate(model, ids, mask, image_mask, embeds,
                                                    max_new_tokens=new_tokens, use_cache=use_cache), repeats=2)
        out["cached" if use_cache else "uncached"] = round(batch * new_tokens / seconds, 1)
    return {"batch": batch, "prompt_tokens": prompt, "new_tokens": new_tokens,
            "tokens_per_s_cached": out["cached"], "tokens_per_s_uncached": out["uncached"],
            "cache_speedup": round(out["cached"] / out["uncached"], 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="small", choices=sorted(config_lib.SIZES))
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--length", type=int, default=128)
    parser.add_argument("--decode-batch", type=int, default=4)
    parser.add_argument("--prompt", type=int, default=96)
    parser.add_argument("--new-tokens", type=int, default=32)
    args = parser.parse_args()
    cfg = config_lib.get_config(args.size)
    # On a shared machine the peak moves with other people's load: measure it before and after the
    # step and divide by the larger (the MFU is then, if anything, understated).
    before = matmul_peak()
    train = train_step_speed(cfg, args.batch, args.length)
    after = matmul_peak()
    peak = max(before["peak_gflops"], after["peak_gflops"])
    for key in ("xla", "formula"):
        train[f"mfu_{key}"] = round(train[f"flops_{key}"] / train["step_seconds"] / 1e9 / peak, 3)
    report = {
        "device": str(jax.devices()[0].device_kind), "backend": jax.default_backend(), "size": args.size,
        "glibc_tunables": os.environ.get("GLIBC_TUNABLES", ""),  # `make bench` sets the Makefile's
        "matmul_float32": {"before": before, "after": after, "peak_gflops": round(peak, 1)},
        "train_step": train,
        "decoding": decoding_speed(cfg, args.decode_batch, args.prompt, args.new_tokens),
    }
    if min(before["peak_gflops"], after["peak_gflops"]) < 0.8 * peak:
        report["warning"] = "matmul peak moved by over 20% during the run: the machine is shared, rerun"
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
