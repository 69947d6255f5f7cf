"""Building blocks shared by the vision tower, the connector and the decoder.

Parameters are float32 and carry logical axis names; matmuls run in the configured compute dtype;
LayerNorm and softmax run in float32. Kernels are stored (in, out), the Flax layout; the importer
transposes PyTorch's (out, in).
"""

from __future__ import annotations

import contextlib
import contextvars
import math

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.config import DROPOUT_MASK_BITS as MASK_BITS
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


_EXAMPLE_IDS: contextvars.ContextVar = contextvars.ContextVar("kosmos_jax_dropout_example_ids", default=None)


@contextlib.contextmanager
def dropout_per_example(example_ids: jax.Array, mask_bits: int = 32):
    """Within it, every `Dropout` draws each row of its input from its own key: row b's mask from
    fold_in(k, example_ids[b]), k being the layer's key for this call. A row's mask then follows its
    example, not its place in the batch, the batch's size, its microbatches or how many processes
    hold it. `example_ids` int [B] (the batch's `example_index`) is read when a Dropout is called
    (traced under jit), so the forward pass runs inside the block. `mask_bits` 32 draws a float32
    uniform an element (jax.random.bernoulli); 16 or 8 compare that many random bits with the rate
    rounded to 1/2^bits, and cost a half or a quarter of the random bits."""
    if mask_bits not in MASK_BITS:
        raise ValueError(f"mask_bits must be one of {MASK_BITS}, got {mask_bits!r}")
    token = _EXAMPLE_IDS.set((example_ids, mask_bits))
    try:
        yield
    finally:
        _EXAMPLE_IDS.reset(token)


class Dropout(nnx.Dropout):
    """nnx.Dropout (same state, same rate and `deterministic` handling) whose mask, inside
    `dropout_per_example`, is drawn row by row from each example's own key; outside it, nnx's one
    mask over the whole input. Off (rate 0 or deterministic) it returns its input, as nnx's does."""

    @property
    def active(self) -> bool:
        """Whether a call without a `deterministic` argument drops anything."""
        return self.deterministic is False and self.rate > 0.0

    def __call__(self, inputs, *, deterministic: bool | None = None, rngs=None):
        per_example = _EXAMPLE_IDS.get()
        deterministic = self.deterministic if deterministic is None else deterministic
        if per_example is None or deterministic is not False or self.rate in (0.0, 1.0):
            return super().__call__(inputs, deterministic=deterministic, rngs=rngs)
        example_ids, mask_bits = per_example
        if 0 in self.broadcast_dims or inputs.shape[:1] != example_ids.shape:
            raise ValueError(f"per-example dropout needs the batch first: input {inputs.shape}, "
                             f"{example_ids.shape} example ids, broadcast_dims {self.broadcast_dims}")
        rngs = self.rngs if rngs is None else rngs
        if isinstance(rngs, nnx.Rngs):
            rngs = rngs[self.rng_collection]
        key = rngs if isinstance(rngs, jax.Array) else rngs()  # a key, or the stream's next one
        row_shape = tuple(1 if dim in self.broadcast_dims else size for dim, size in enumerate(inputs.shape))[1:]
        keys = jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, example_ids)
        if mask_bits == 32:
            keep = 1.0 - self.rate
            draw = lambda k: jax.random.bernoulli(k, keep, row_shape)
        else:  # dropped where the bits fall below the rate's share of their 2^bits values
            levels = 2**mask_bits
            dropped = min(max(round(self.rate * levels), 1), levels - 1)
            keep = 1.0 - dropped / levels
            draw = lambda k: _split_bits(k, row_shape, mask_bits) >= dropped
        mask = jnp.broadcast_to(jax.vmap(draw)(keys), inputs.shape)
        return jax.lax.select(mask, inputs / keep, jnp.zeros_like(inputs))


def _split_bits(key, shape: tuple[int, ...], bits: int) -> jax.Array:
    """Uniform `bits`-bit integers of `shape`, 32 // bits from each 32-bit word drawn. (jax.random.bits
    with a narrower dtype draws a whole word an element under jax's partitionable threefry: no saving.)"""
    per_word, size = 32 // bits, math.prod(shape)
    words = jax.random.bits(key, (-(-size // per_word),), jnp.uint32)
    parts = [(words >> (bits * i)) & (2**bits - 1) for i in range(per_word)]
    return jnp.stack(parts, axis=-1).reshape(-1)[:size].reshape(shape)


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


def dot_product_attention(q, k, v, mask, dropout: Dropout | None = None, kernel: str = "einsum"):
    """q [B,T,H,D], k/v [B,S,H,D], mask broadcastable to [B,H,T,S] (True = attend) or None.

    Scores and softmax in float32. A row with no allowed key (a padding query) gets uniform
    weights instead of NaN, as PyTorch's additive finfo.min mask does. `kernel` "fused" hands the
    whole product to jax.nn.dot_product_attention (cuDNN where it can, XLA elsewhere), unless
    `dropout` is active.
    """
    if kernel == "fused" and not (dropout is not None and dropout.active):
        # jax masks with a large finite negative: a row with no allowed key gets uniform weights too
        return constrain(jax.nn.dot_product_attention(q, k, v, mask=mask), HEADS)
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


REMAT_SAVED = {"full": None, "dots": jax.checkpoint_policies.dots_with_no_batch_dims_saveable}


def rematerialised(call, enabled: bool, in_scan: bool, policy: str = "full"):
    """`call` under nnx.remat when enabled: its activations are recomputed in the backward pass, but
    for those `policy` (a Kosmos2Config.remat_policy) keeps."""
    if not enabled:
        return call
    # Under scan the recomputation cannot be merged with the forward pass, so CSE need not be
    # blocked (jax.checkpoint's advice); blocking it there only costs speed.
    return nnx.remat(call, prevent_cse=not in_scan, policy=REMAT_SAVED[policy])
