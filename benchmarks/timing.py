"""Timing helpers the benchmarks share: the best of several calls, and the float32 matmul peak."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp


def best_time(fn, *args, repeats: int = 5) -> float:
    jax.block_until_ready(fn(*args))  # compile and warm up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return min(times)


def interleaved_times(calls: dict, rounds: int = 8) -> dict:
    """Each of `calls` (name -> function of no argument) timed once a round, in turn, for `rounds`
    rounds after one warm-up call each: a neighbour's load then falls on every contestant alike.
    name -> {"min": seconds, "median": seconds, "rounds": every round's seconds}."""
    for call in calls.values():
        jax.block_until_ready(call())
    times = {name: [] for name in calls}
    for _ in range(rounds):
        for name, call in calls.items():
            start = time.perf_counter()
            jax.block_until_ready(call())
            times[name].append(time.perf_counter() - start)
    return {name: {"min": min(t), "median": sorted(t)[len(t) // 2], "rounds": [round(x, 4) for x in t]}
            for name, t in times.items()}


def matmul_peak(sizes=(1024, 2048, 4096)) -> dict:
    """Best float32 GFLOP/s over square matmuls."""
    results = {}
    for n in sizes:
        a = jax.random.normal(jax.random.key(0), (n, n), jnp.float32)
        b = jax.random.normal(jax.random.key(1), (n, n), jnp.float32)
        t = best_time(jax.jit(jnp.matmul), a, b, repeats=3 if n >= 4096 else 5)
        results[n] = 2 * n**3 / t / 1e9
    return {"gflops_by_size": {str(k): round(v, 1) for k, v in results.items()}, "peak_gflops": max(results.values())}
