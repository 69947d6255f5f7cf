"""Per-layer fwd+bwd times of GR-ConvNet c=16 RGB-D batch 8 layers: project JAX layer vs torch."""
import json, os, sys, time
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[4] / "benchmarks"))
import jax, jax.numpy as jnp, numpy as np
from flax import nnx
import torch
from timing import interleaved_times
from kosmos_jax.baselines.layers import conv, conv_transpose

B = 8
LAYERS = [  # name, kind, cin, cout, k, stride, H_in
    ("conv1_9x9", "conv", 4, 16, 9, 1, 224),
    ("conv2_4x4s2", "conv", 16, 32, 4, 2, 224),
    ("conv3_4x4s2", "conv", 32, 64, 4, 2, 112),
    ("res_3x3", "conv", 64, 64, 3, 1, 56),
    ("up1_T4x4s2", "convT", 64, 32, 4, 2, 56),
    ("up2_T4x4s2", "convT", 32, 16, 4, 2, 112),
    ("up3_T9x9", "convT", 16, 16, 9, 1, 224),
    ("heads_2x2", "conv", 16, 4, 2, 1, 224),
]

def jax_call(kind, cin, cout, k, s, h):
    rngs = nnx.Rngs(0)
    m = conv(cin, cout, k, stride=s, rngs=rngs) if kind == "conv" else conv_transpose(cin, cout, k, stride=s, rngs=rngs)
    g, p = nnx.split(m)
    x = jax.random.normal(jax.random.key(1), (B, h, h, cin))
    def loss(p, x):
        y = nnx.merge(g, p)(x)
        return jnp.sum(y * y) * 0.5
    f = jax.jit(jax.grad(loss, argnums=(0, 1)))
    fw = jax.jit(lambda p, x: nnx.merge(g, p)(x))
    return (lambda: f(p, x)), (lambda: fw(p, x))

def torch_call(kind, cin, cout, k, s, h):
    pad = (k - 1) // 2 if s == 1 else 1
    if kind == "conv":
        if k == 2:
            m = torch.nn.Sequential(torch.nn.ZeroPad2d((0, 1, 0, 1)), torch.nn.Conv2d(cin, cout, k))
        else:
            m = torch.nn.Conv2d(cin, cout, k, stride=s, padding=pad)
    else:
        m = torch.nn.ConvTranspose2d(cin, cout, k, stride=s, padding=(k - s + 1) // 2)
    x = torch.randn(B, cin, h, h, requires_grad=True)
    def step():
        m.zero_grad(set_to_none=True); x.grad = None
        y = m(x); (0.5 * (y * y).sum()).backward()
        return 0.0
    def fwd():
        with torch.no_grad():
            m(x)
        return 0.0
    return step, fwd

out = {}
for name, *spec in LAYERS:
    jb, jf = jax_call(*spec)
    tb, tf = torch_call(*spec)
    t = interleaved_times({"jax_fb": jb, "torch_fb": tb, "jax_f": jf, "torch_f": tf}, rounds=int(os.environ.get("ROUNDS", 4)))
    out[name] = {k: round(v["min"] * 1e3, 2) for k, v in t.items()}
    print(name, out[name], flush=True)
print(json.dumps({"xla_flags": os.environ.get("XLA_FLAGS"), "torch_threads": torch.get_num_threads(), "ms": out}))
