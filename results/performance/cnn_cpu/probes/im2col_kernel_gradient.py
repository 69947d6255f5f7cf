import time, jax, jax.numpy as jnp, numpy as np
from jax import lax
import sys
sys.path.insert(0, "results/performance/cnn_cpu/probes")
from im2col import conv_lax, timeit

def wgrad_im2col(x, g, k):
    p = k // 2
    b, h, wd, cin = x.shape
    xp = jnp.pad(x, ((0, 0), (p, k - 1 - p), (p, k - 1 - p), (0, 0)))
    cols = jnp.concatenate([xp[:, i:i + h, j:j + wd] for i in range(k) for j in range(k)], axis=-1)
    return jnp.einsum("bhwk,bhwo->ko", cols, g).reshape(k, k, cin, g.shape[-1])

def wgrad_taps(x, g, k):
    p = k // 2
    b, h, wd, cin = x.shape
    xp = jnp.pad(x, ((0, 0), (p, k - 1 - p), (p, k - 1 - p), (0, 0)))
    return jnp.stack([jnp.stack([jnp.einsum("bhwc,bhwo->co", xp[:, i:i + h, j:j + wd], g) for j in range(k)]) for i in range(k)])

rng = np.random.default_rng(0)
for (cin, cout, k) in [(4, 16, 9), (16, 16, 9)]:
    x = jnp.asarray(rng.normal(size=(8, 224, 224, cin)), jnp.float32)
    w = jnp.asarray(rng.normal(size=(k, k, cin, cout)) * 0.1, jnp.float32)
    g = jnp.asarray(rng.normal(size=(8, 224, 224, cout)), jnp.float32)
    _, vjp = jax.vjp(conv_lax, x, w)
    ref_dx, ref_dw = vjp(g)
    dx_only = jax.jit(lambda x, w, g: jax.vjp(lambda x: conv_lax(x, w), x)[1](g)[0])
    dw_only = jax.jit(lambda x, w, g: jax.vjp(lambda w: conv_lax(x, w), w)[1](g)[0])
    a = jax.jit(lambda x, g: wgrad_im2col(x, g, k)); b = jax.jit(lambda x, g: wgrad_taps(x, g, k))
    print(cin, cout, k, "dx lax", timeit(dx_only, x, w, g)[0], "dw lax", timeit(dw_only, x, w, g)[0],
          "dw im2col", timeit(a, x, g)[0], float(jnp.max(jnp.abs(a(x, g) - ref_dw)) / jnp.max(jnp.abs(ref_dw))),
          "dw taps", timeit(b, x, g)[0], flush=True)
