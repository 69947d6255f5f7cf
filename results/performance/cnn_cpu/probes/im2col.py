import time, jax, jax.numpy as jnp, numpy as np
from jax import lax

def conv_lax(x, w):
    return lax.conv_general_dilated(x, w, (1, 1), "SAME", dimension_numbers=("NHWC", "HWIO", "NHWC"))

def conv_im2col(x, w):
    k, _, cin, cout = w.shape
    p = k // 2
    b, h, wd, _ = x.shape
    xp = jnp.pad(x, ((0, 0), (p, k - 1 - p), (p, k - 1 - p), (0, 0)))
    cols = jnp.concatenate([xp[:, i:i + h, j:j + wd] for i in range(k) for j in range(k)], axis=-1)
    return jnp.einsum("bhwk,ko->bhwo", cols, w.reshape(k * k * cin, cout))

def timeit(f, *a, n=5):
    jax.block_until_ready(f(*a))
    ts = []
    for _ in range(n):
        t = time.perf_counter(); jax.block_until_ready(f(*a)); ts.append(time.perf_counter() - t)
    return min(ts), np.median(ts)

rng = np.random.default_rng(0)
for (cin, cout, k) in [(4, 16, 9), (3, 16, 9), (16, 16, 9), (16, 4, 2), (64, 64, 3)]:
    hw = 56 if cin == 64 else 224
    x = jnp.asarray(rng.normal(size=(8, hw, hw, cin)), jnp.float32)
    w = jnp.asarray(rng.normal(size=(k, k, cin, cout)) * 0.1, jnp.float32)
    ya, yb = conv_lax(x, w), conv_im2col(x, w)
    err = float(jnp.max(jnp.abs(ya - yb)) / jnp.max(jnp.abs(ya)))
    for name, f in [("lax", conv_lax), ("im2col", conv_im2col)]:
        loss = lambda x, w: jnp.sum(f(x, w) ** 2)
        fwd = jax.jit(f)
        grad = jax.jit(jax.grad(loss, argnums=(0, 1)))
        print(f"cin {cin} cout {cout} k {k} hw {hw} {name:7s} fwd {timeit(fwd, x, w)[0]:.4f}s fwd+bwd {timeit(grad, x, w)[0]:.4f}s relerr {err:.1e}", flush=True)
