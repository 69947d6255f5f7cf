"""Building blocks shared by the vision tower, the connector and the decoder.

Parameters are float32 and carry logical axis names; matmuls run in the configured compute dtype;
LayerNorm and softmax run in float32. Kernels are stored (in, out), the Flax layout; the importer
transposes PyTorch's (out, in).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.sharding import constrain, logical

ACT = ("batch", "length", "act_embed")  # [B, T, D]: the residual stream and the connector output
HEADS = ("batch", "length", "act_heads", "kv")  # [B, T, H, Dh]: attention outputs and the KV cache


def dense(in_features: int, out_features: int, axes: tuple[str, str], rngs: nnx.Rngs, *, std: float,
          dtype=jnp.float32, use_bias: bool = True) -> nnx.Linear:
    return nnx.Linear(
        in_features, out_features, use_bias=use_bias, dtype=dtype, param_dtype=jnp.float32,
        kernel_init=logical(jax.nn.initializers.normal(std), axes),
        bias_init=logical(jax.nn.initializers.zeros, (axes[1],)),
        rngs=rngs,
    )


class LayerNorm(nnx.LayerNorm):
    """PyTorch's LayerNorm: eps 1e-5, exact two-pass variance, computed in float32, cast back."""

    def __init__(self, features: int, eps: float, rngs: nnx.Rngs, axis_name: str = "norm"):
        super().__init__(
            features, epsilon=eps, dtype=jnp.float32, param_dtype=jnp.float32, use_fast_variance=False,
            scale_init=logical(jax.nn.initializers.ones, (axis_name,)),
            bias_init=logical(jax.nn.initializers.zeros, (axis_name,)),
            rngs=rngs,
        )

    def __call__(self, x):
        return super().__call__(x.astype(jnp.float32)).astype(x.dtype)


def gelu_exact(x):
    return jax.nn.gelu(x, approximate=False)  # PyTorch's nn.GELU() default: erf, not tanh


def quick_gelu(x):
    return x * jax.nn.sigmoid(1.702 * x)


def split_heads(x: jax.Array, num_heads: int) -> jax.Array:
    return x.reshape(*x.shape[:-1], num_heads, x.shape[-1] // num_heads)


def attention_scores(q, k):
    """q [B,T,H,D], k [B,S,H,D] -> scaled dot products [B,H,T,S] in float32."""
    # heads-major layout for the batched matmul: about 2x faster on CPU than contracting in place
    q, k = (x.transpose(0, 2, 1, 3) for x in (q, k))
    return jnp.einsum("bhtd,bhsd->bhts", q, k, preferred_element_type=jnp.float32) * q.shape[-1] ** -0.5


def dot_product_attention(q, k, v, mask, dropout: nnx.Dropout | None = None):
    """q [B,T,H,D], k/v [B,S,H,D], mask broadcastable to [B,H,T,S] (True = attend) or None.

    Scores and softmax in float32. A row with no allowed key (a padding query) gets uniform
    weights instead of NaN, as PyTorch's additive finfo.min mask does.
    """
    scores = attention_scores(q, k)
    v = v.transpose(0, 2, 1, 3)
    if mask is not None:
        scores = jnp.where(mask, scores, jnp.finfo(jnp.float32).min)
    weights = jax.nn.softmax(scores, axis=-1)
    if dropout is not None:
        weights = dropout(weights)
    out = jnp.einsum("bhts,bhsd->bhtd", weights.astype(v.dtype), v).transpose(0, 2, 1, 3)
    return constrain(out, HEADS)


# -- stacks of blocks: a Python list (one copy of each block in the program) or one scanned module --
LAYERS = "layers"  # logical name of the leading axis of stacked blocks' variables
_STACKED = {nnx.PARTITION_NAME: LAYERS, "logical_axes": LAYERS}  # vmap prepends it to every logical_axes


def stack_blocks(make_block, count: int, rngs: nnx.Rngs) -> nnx.Module:
    """`count` blocks made by `make_block(rngs)` as ONE module whose variables carry a leading [count]
    axis; every block draws from its own split of each rng stream (own init, own dropout masks)."""

    @nnx.split_rngs(splits=count)
    @nnx.vmap(in_axes=(0,), out_axes=0, transform_metadata=_STACKED)
    def create(rngs):
        return make_block(rngs)

    return create(rngs)


def scan_blocks(call, blocks: nnx.Module, x, per_layer, *shared):
    """x through the stacked `blocks` in order, `x, out_i = call(block_i, x, per_layer_i, *shared)`;
    returns (x, the outs stacked on a leading axis). `per_layer` has a leading [count] axis (or is None)."""

    @nnx.scan(in_axes=(0, nnx.Carry, 0) + (None,) * len(shared), out_axes=(nnx.Carry, 0))
    def body(block, x, per_layer, *shared):
        return call(block, x, per_layer, *shared)

    return body(blocks, x, per_layer, *shared)


def rematerialised(call, enabled: bool, in_scan: bool):
    """`call` under nnx.remat when enabled: its activations are recomputed in the backward pass."""
    if not enabled:
        return call
    # Under scan the recomputation cannot be merged with the forward pass, so CSE need not be
    # blocked (jax.checkpoint's advice); blocking it there only costs speed.
    return nnx.remat(call, prevent_cse=not in_scan)
