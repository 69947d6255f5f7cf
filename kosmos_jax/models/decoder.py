"""The MAGNETO (Sub-LN) decoder of KOSMOS-2, attribute names mirroring `text_model.model.*`.

A key-value cache is a plain pytree passed in and returned (static shapes, so it lives inside jit):
`{"k": [L x [B, S, H, Dh]], "v": [...], "valid": [B, S] bool, "index": int32}` where `index` is the
slot the next token is written to and `valid` marks slots holding real (non-padding) tokens. With
scanned layers (`scan_layers`) "k" and "v" are instead single [L, B, S, H, Dh] arrays.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.config import TextConfig
from kosmos_jax.models.layers import (ACT, HEADS, LAYERS, Dropout, LayerNorm, dense, dot_product_attention, gelu_exact,
                                      rematerialised, scan_blocks, split_heads, stack_blocks)
from kosmos_jax.models.sharding import constrain, logical


class TextAttention(nnx.Module):
    """KosmosTextAttention: biased q/k/v/out projections, optional Sub-LN before out_proj."""

    def __init__(self, cfg: TextConfig, dtype, rngs: nnx.Rngs, *, inner_layernorm: bool, attention: str = "einsum"):
        d = cfg.embed_dim
        self.kernel = attention
        self.num_heads = cfg.attention_heads
        self.k_proj = dense(d, d, ("embed", "heads"), rngs, std=cfg.init_std, dtype=dtype)
        self.v_proj = dense(d, d, ("embed", "heads"), rngs, std=cfg.init_std, dtype=dtype)
        self.q_proj = dense(d, d, ("embed", "heads"), rngs, std=cfg.init_std, dtype=dtype)
        self.out_proj = dense(d, d, ("heads", "embed"), rngs, std=cfg.init_std, dtype=dtype)
        self.inner_attn_ln = LayerNorm(d, cfg.layer_norm_eps, rngs, "norm") if inner_layernorm else None
        self.attn_dropout = Dropout(cfg.attention_dropout, rngs=rngs)

    def __call__(self, x, mask, kv_input=None, layer_cache=None, index=None):
        """x [B,T,D]; keys from `kv_input` (default x). With `layer_cache` (k, v), the new keys are
        written at slot `index` and attention runs over the whole cache; returns (out, (k, v))."""
        kv_input = x if kv_input is None else kv_input
        q = split_heads(self.q_proj(x), self.num_heads)
        k = split_heads(self.k_proj(kv_input), self.num_heads)
        v = split_heads(self.v_proj(kv_input), self.num_heads)
        if layer_cache is not None:
            k_cache, v_cache = layer_cache
            k = constrain(jax.lax.dynamic_update_slice(k_cache, k.astype(k_cache.dtype), (0, index, 0, 0)), HEADS)
            v = constrain(jax.lax.dynamic_update_slice(v_cache, v.astype(v_cache.dtype), (0, index, 0, 0)), HEADS)
            layer_cache = (k, v)
        out = dot_product_attention(q, k, v, mask, self.attn_dropout, self.kernel)
        out = out.reshape(*out.shape[:2], -1)
        if self.inner_attn_ln is not None:
            out = self.inner_attn_ln(out)
        return self.out_proj(out), layer_cache


class TextFFN(nnx.Module):
    def __init__(self, cfg: TextConfig, dtype, rngs: nnx.Rngs):
        self.fc1 = dense(cfg.embed_dim, cfg.ffn_dim, ("embed", "mlp"), rngs, std=cfg.init_std, dtype=dtype)
        self.fc2 = dense(cfg.ffn_dim, cfg.embed_dim, ("mlp", "embed"), rngs, std=cfg.init_std, dtype=dtype)
        self.ffn_layernorm = LayerNorm(cfg.ffn_dim, cfg.layer_norm_eps, rngs, "norm")
        self.activation_dropout = Dropout(cfg.activation_dropout, rngs=rngs)
        self.dropout = Dropout(cfg.dropout, rngs=rngs)

    def __call__(self, x):
        h = constrain(gelu_exact(self.fc1(x)), ("batch", "length", "act_mlp"))
        h = self.ffn_layernorm(self.activation_dropout(h))
        return self.dropout(self.fc2(h))


class TextBlock(nnx.Module):
    def __init__(self, cfg: TextConfig, dtype, rngs: nnx.Rngs, magneto_gain: float = 1.0, attention: str = "einsum"):
        self.self_attn = TextAttention(cfg, dtype, rngs, inner_layernorm=True, attention=attention)
        self.self_attn_layer_norm = LayerNorm(cfg.embed_dim, cfg.layer_norm_eps, rngs)
        self.ffn = TextFFN(cfg, dtype, rngs)
        self.final_layer_norm = LayerNorm(cfg.embed_dim, cfg.layer_norm_eps, rngs)  # the pre-FFN LN
        self.dropout = Dropout(cfg.dropout, rngs=rngs)
        if magneto_gain != 1.0:  # MAGNETO: sqrt(log 2N) on fc1, fc2, out_proj, v_proj
            for linear in (self.ffn.fc1, self.ffn.fc2, self.self_attn.out_proj, self.self_attn.v_proj):
                linear.kernel.set_value(linear.kernel.get_value() * magneto_gain)
                linear.bias.set_value(linear.bias.get_value() * magneto_gain)

    def __call__(self, x, mask, layer_cache=None, index=None):
        h, layer_cache = self.self_attn(self.self_attn_layer_norm(x), mask, layer_cache=layer_cache, index=index)
        x = x + self.dropout(h)
        x = x + self.ffn(self.final_layer_norm(x))
        return constrain(x, ACT), layer_cache


def sinusoidal_positions(positions: jax.Array, dim: int, padding_idx: int) -> jax.Array:
    """fairseq's table row for each position id: [sin | cos] halves, the padding row all zero."""
    half = dim // 2
    freq = jnp.exp(jnp.arange(half, dtype=jnp.float32) * -(math.log(10000.0) / (half - 1)))
    angles = positions.astype(jnp.float32)[..., None] * freq
    emb = jnp.concatenate([jnp.sin(angles), jnp.cos(angles)], axis=-1)
    if dim % 2:
        emb = jnp.pad(emb, [(0, 0)] * (emb.ndim - 1) + [(0, 1)])
    return jnp.where((positions == padding_idx)[..., None], 0.0, emb)


def position_ids(attention_mask: jax.Array, padding_idx: int, start: jax.Array | int = 0) -> jax.Array:
    """KOSMOS-2 positions: real tokens count from padding_idx + 1 (= 2), padding gets padding_idx.

    `start` [B] is the number of real tokens already before this chunk (for cached decoding).
    """
    real = attention_mask.astype(jnp.int32)
    return (jnp.cumsum(real, axis=1) + jnp.asarray(start, jnp.int32)[..., None]) * real + padding_idx


def scatter_image_embeds(token_embeds, image_embeds, image_mask):
    """Write image_embeds [B, Q, D] into the slots where image_mask [B, T] is True, in order."""
    if image_embeds is None:
        return token_embeds
    slot = jnp.clip(jnp.cumsum(image_mask.astype(jnp.int32), axis=1) - 1, 0, image_embeds.shape[1] - 1)
    gathered = jnp.take_along_axis(image_embeds.astype(token_embeds.dtype), slot[..., None], axis=1)
    return jnp.where(image_mask[..., None], gathered, token_embeds)


def _block_step(layer: TextBlock, x, layer_cache, mask, index):
    """One block in scan_blocks' argument order: the carry, the per-layer input, the shared ones."""
    return layer(x, mask, layer_cache, index)


class TextTransformer(nnx.Module):
    def __init__(self, cfg: TextConfig, dtype, rngs: nnx.Rngs, magneto_gain: float = 1.0, *,
                 scan_layers: bool = False, remat: bool = False, remat_policy: str = "full", attention: str = "einsum"):
        self.cfg = cfg
        self.dtype = dtype
        self.scan_layers = scan_layers
        self.remat = remat
        self.remat_policy = remat_policy
        self.embed_scale = math.sqrt(cfg.embed_dim) if cfg.scale_embedding else 1.0
        # std d^-0.5: the scaled embedding has unit variance (fairseq's choice for tied embeddings)
        self.embed_tokens = nnx.Embed(
            cfg.vocab_size, cfg.embed_dim, param_dtype=jnp.float32,
            embedding_init=logical(jax.nn.initializers.normal(cfg.embed_dim**-0.5), ("vocab", "embed")),
            rngs=rngs,
        )
        if scan_layers:
            self.layers = stack_blocks(lambda r: TextBlock(cfg, dtype, r, magneto_gain, attention), cfg.layers, rngs)
        else:
            self.layers = nnx.List([TextBlock(cfg, dtype, rngs, magneto_gain, attention) for _ in range(cfg.layers)])
        self.layer_norm = LayerNorm(cfg.embed_dim, cfg.layer_norm_eps, rngs)
        self.dropout = Dropout(cfg.dropout, rngs=rngs)

    def embed(self, input_ids, positions, image_embeds=None, image_mask=None):
        # transformers applies embedding dropout twice (in forward_embedding and again in forward);
        # fairseq/torchscale, which trained KOSMOS-2, once. Once here; identical in eval mode.
        x = jnp.take(self.embed_tokens.embedding[...], input_ids, axis=0)
        x = scatter_image_embeds(x, image_embeds, image_mask) * self.embed_scale
        x = x + sinusoidal_positions(positions, self.cfg.embed_dim, self.cfg.pad_token_id)
        return constrain(self.dropout(x).astype(self.dtype), ACT)

    def __call__(self, input_ids, attention_mask, positions, image_embeds=None, image_mask=None, cache=None):
        """Final hidden states [B, T, D] (float32) and the updated cache (None without one)."""
        x = self.embed(input_ids, positions, image_embeds, image_mask)
        t = input_ids.shape[1]
        attention_mask = attention_mask.astype(bool)
        if cache is None:
            causal = jnp.tril(jnp.ones((t, t), bool))
            mask = causal[None, None] & attention_mask[:, None, None, :]
            index, new_cache = None, None
        else:
            index = cache["index"]
            valid = jax.lax.dynamic_update_slice(cache["valid"], attention_mask, (0, index))
            slots = jnp.arange(valid.shape[1])
            causal = slots[None, :] <= (index + jnp.arange(t))[:, None]
            mask = causal[None, None] & valid[:, None, None, :]
            new_cache = {"k": [], "v": [], "valid": valid, "index": index + t}
        block = rematerialised(_block_step, self.remat, in_scan=self.scan_layers, policy=self.remat_policy)
        if self.scan_layers:
            stacked_cache = None if cache is None else (cache["k"], cache["v"])
            x, stacked_cache = scan_blocks(block, self.layers, x, stacked_cache, mask, index)
            if cache is not None:
                new_cache["k"], new_cache["v"] = stacked_cache
        else:
            for i, layer in enumerate(self.layers):
                layer_cache = None if cache is None else (cache["k"][i], cache["v"][i])
                x, layer_cache = block(layer, x, layer_cache, mask, index)
                if cache is not None:
                    new_cache["k"].append(layer_cache[0])
                    new_cache["v"].append(layer_cache[1])
        return self.layer_norm(x).astype(jnp.float32), new_cache


class TextForCausalLM(nnx.Module):
    """`text_model`: the decoder plus the LM head tied to `embed_tokens` (no parameter of its own)."""

    def __init__(self, cfg: TextConfig, dtype, rngs: nnx.Rngs, magneto_gain: float = 1.0, **layout):
        """`layout`: TextTransformer's scan_layers, remat, remat_policy and attention."""
        self.model = TextTransformer(cfg, dtype, rngs, magneto_gain, **layout)

    def logits(self, hidden):
        table = self.model.embed_tokens.embedding[...]
        out = jnp.einsum("btd,vd->btv", hidden.astype(self.model.dtype), table.astype(self.model.dtype),
                         preferred_element_type=jnp.float32)
        return constrain(out, ("batch", "length", "act_vocab"))


def init_cache(cfg: TextConfig, batch: int, max_len: int, dtype=jnp.float32, stacked: bool = False) -> dict:
    """An empty cache; `stacked` gives the scanned layout ([L, ...] arrays instead of lists)."""
    head_dim = cfg.embed_dim // cfg.attention_heads
    shape = (batch, max_len, cfg.attention_heads, head_dim)
    if stacked:
        k, v = (constrain(jnp.zeros((cfg.layers, *shape), dtype), (LAYERS, *HEADS)) for _ in range(2))
    else:
        k, v = ([constrain(jnp.zeros(shape, dtype), HEADS) for _ in range(cfg.layers)] for _ in range(2))
    return {
        "k": k,
        "v": v,
        "valid": constrain(jnp.zeros((batch, max_len), bool), ("batch", "length")),
        "index": jnp.zeros((), jnp.int32),
    }
