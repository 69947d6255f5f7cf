"""Dropout's masks: the trainer's per-example masks (`layers.dropout_per_example`) from 32, 16 and 8 random
bits an element against nnx.Dropout's one mask over the batch (the peer), interleaved in one run.

    GLIBC_TUNABLES=glibc.malloc.hugetlb=1 .venv/bin/python benchmarks/dropout_masks.py [--shape 8,8,256,256] [--rounds 8]

The default shape is attention weights [B, H, T, T] of 8 sequences of 256 tokens (the paper step's length)
with 8 heads: one attention-dropout mask, of the kind the largest masks of a step are. Each contestant
applies rate-0.1 dropout to the same float32 array under jit; the table gives each one's median and best
over the rounds and the median's ratio to the peer's.
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp
from flax import nnx

from timing import interleaved_times  # benchmarks/timing.py, beside this script
from kosmos_jax.models import layers


KEY = jax.random.key(0)  # each layer's key given to the call: no stream state to carry under jit


def per_example(x, ids, bits: int):
    dropout = layers.Dropout(0.1, deterministic=False)

    @jax.jit
    def apply(x, ids, key):
        with layers.dropout_per_example(ids, bits):
            return dropout(x, rngs=key)

    return lambda: apply(x, ids, KEY)


def nnx_mask(x):
    dropout = nnx.Dropout(0.1, deterministic=False)
    apply = jax.jit(lambda x, key: dropout(x, rngs=key))
    return lambda: apply(x, KEY)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shape", default="8,8,256,256", help="the masked array's shape, batch first")
    parser.add_argument("--rounds", type=int, default=8)
    parser.add_argument("--json", action="store_true", help="print the figures as one JSON line instead")
    args = parser.parse_args()
    shape = tuple(int(n) for n in args.shape.split(","))
    if len(shape) < 2 or min(shape) < 1:
        parser.error(f"--shape needs two or more positive sizes, got {args.shape!r}")
    x = jax.random.normal(jax.random.key(1), shape, jnp.float32)
    ids = jnp.arange(shape[0])
    calls = {"nnx.Dropout (peer)": nnx_mask(x), **{f"per-example, {bits} bits": per_example(x, ids, bits)
                                                    for bits in layers.MASK_BITS}}
    times = interleaved_times(calls, rounds=args.rounds)
    peer = times["nnx.Dropout (peer)"]["median"]
    if args.json:
        print(json.dumps({"shape": shape, "device": jax.devices()[0].device_kind, **times}))
        return
    print(f"dropout masks, rate 0.1, shape {shape}, {jax.devices()[0].device_kind}, {args.rounds} rounds")
    print(f"{'contestant':24} {'median ms':>10} {'best ms':>8} {'median / peer':>14}")
    for name, t in times.items():
        print(f"{name:24} {t['median'] * 1e3:10.2f} {t['min'] * 1e3:8.2f} {t['median'] / peer:14.2f}")


if __name__ == "__main__":
    main()
