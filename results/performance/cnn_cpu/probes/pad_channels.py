"""9x9 convolutions at 224 px, batch 8: output channels zero-padded to 17, 20 or 24 (and cut) so that YNNPACK takes them; forward, input and kernel gradient apart (ms, best of 3). Run: .venv/bin/python results/performance/cnn_cpu/probes/pad_channels.py"""
import sys
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[4] / "benchmarks"))
import jax, jax.numpy as jnp
from timing import interleaved_times
dn = ("NHWC", "HWIO", "NHWC"); B, H = 8, 224
def conv(x, w, out=None):
    k = w.shape[0]
    if out: w = jnp.pad(w, [(0, 0)] * 3 + [(0, out - w.shape[3])])
    y = jax.lax.conv_general_dilated(x, w, (1, 1), [(k // 2, k // 2)] * 2, dimension_numbers=dn)
    return y[..., :16] if out else y
res = {}
for cin in (16, 4):
    x = jax.random.normal(jax.random.key(0), (B, H, H, cin)); w = jax.random.normal(jax.random.key(1), (9, 9, cin, 16)) * 0.05
    g = jax.random.normal(jax.random.key(2), (B, H, H, 16))
    c = {}
    for out in (None, 17, 20, 24):
        c[f"fwd_{out}"] = jax.jit(lambda x, w, out=out: conv(x, w, out))
        c[f"dx_{out}"] = jax.jit(jax.grad(lambda x, w, out=out: jnp.sum(conv(x, w, out) * g), argnums=0))
        c[f"dw_{out}"] = jax.jit(jax.grad(lambda x, w, out=out: jnp.sum(conv(x, w, out) * g), argnums=1))
    calls = {k: (lambda f=f: f(x, w)) for k, f in c.items()}
    t = interleaved_times(calls, rounds=3)
    res[cin] = {k: round(v["min"] * 1e3, 1) for k, v in t.items()}
    print(cin, res[cin], flush=True)
