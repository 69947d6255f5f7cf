"""up3 (9x9 16->16 @224) and conv1 (9x9 4->16 @224) at batch 8: where the time goes, and variants."""
import json, os, sys
sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[4] / "benchmarks"))
import jax, jax.numpy as jnp
import torch
from timing import interleaved_times
dn = ("NHWC", "HWIO", "NHWC")
B, H = 8, 224

def conv(x, w, out=None, dtype=None):
    k = w.shape[0]
    if out:  # zero output channels up to `out`, cut after: same function, channels > 16 for YNNPACK
        w = jnp.pad(w, [(0, 0), (0, 0), (0, 0), (0, out - w.shape[3])])
    if dtype:
        x, w = x.astype(dtype), w.astype(dtype)
    y = jax.lax.conv_general_dilated(x, w, (1, 1), [(k // 2, k // 2)] * 2, dimension_numbers=dn,
                                     preferred_element_type=jnp.float32)
    return y[..., :16] if out else y

def calls(cin):
    x = jax.random.normal(jax.random.key(0), (B, H, H, cin)); w = jax.random.normal(jax.random.key(1), (9, 9, cin, 16)) * 0.05
    g = jax.random.normal(jax.random.key(2), (B, H, H, 16))
    c = {}
    c["f32_fwd"] = jax.jit(lambda x, w: conv(x, w))
    c["f32_dx"] = jax.jit(jax.grad(lambda x, w: jnp.sum(conv(x, w) * g), argnums=0))
    c["f32_dw"] = jax.jit(jax.grad(lambda x, w: jnp.sum(conv(x, w) * g), argnums=1))
    argn = (0, 1) if cin == 16 else 1
    c["f32_fb"] = jax.jit(jax.grad(lambda x, w: jnp.sum(conv(x, w) * g), argnums=argn))
    c["pad32_fb"] = jax.jit(jax.grad(lambda x, w: jnp.sum(conv(x, w, out=32) * g), argnums=argn))
    c["bf16_fb"] = jax.jit(jax.grad(lambda x, w: jnp.sum(conv(x, w, dtype=jnp.bfloat16) * g), argnums=argn))
    out = {k: (lambda f=f: f(x, w)) for k, f in c.items()}
    m = torch.nn.Conv2d(cin, 16, 9, padding=4)
    tx = torch.randn(B, cin, H, H, requires_grad=(cin == 16)); tg = torch.randn(B, 16, H, H)
    def tfb():
        m.zero_grad(set_to_none=True); tx.grad = None
        (m(tx) * tg).sum().backward(); return 0.0
    out["torch_fb"] = tfb
    return out

res = {}
for name, cin in (("up3_16to16", 16), ("conv1_4to16", 4)):
    t = interleaved_times(calls(cin), rounds=int(os.environ.get("ROUNDS", 3)))
    res[name] = {k: round(v["min"] * 1e3, 1) for k, v in t.items()}
    print(name, res[name], flush=True)
print(json.dumps({"xla_flags": os.environ.get("XLA_FLAGS"), "load": os.getloadavg(), "ms": res}))
