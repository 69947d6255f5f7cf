"""The CLIP ViT-L/14 vision tower of KOSMOS-2, attribute names mirroring `vision_model.model.*`."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.config import VisionConfig
from kosmos_jax.models.layers import (ACT, Dropout, LayerNorm, dense, dot_product_attention, quick_gelu, rematerialised,
                                      scan_blocks, split_heads, stack_blocks)
from kosmos_jax.models.sharding import constrain, logical


class VisionEmbeddings(nnx.Module):
    def __init__(self, cfg: VisionConfig, dtype, rngs: nnx.Rngs):
        d, std = cfg.hidden_size, cfg.initializer_range
        self.patch_size = cfg.patch_size
        self.image_size = cfg.image_size
        self.dtype = dtype
        self.class_embedding = nnx.Param(jax.random.normal(rngs.params(), (d,)) * d**-0.5, logical_axes=("embed",))
        self.patch_embedding = nnx.Conv(
            cfg.num_channels, d, (cfg.patch_size, cfg.patch_size), strides=cfg.patch_size, padding="VALID",
            use_bias=False, dtype=dtype, param_dtype=jnp.float32,
            kernel_init=logical(jax.nn.initializers.normal(std), ("patch", "patch", "patch", "embed")),
            rngs=rngs,
        )
        self.position_embedding = nnx.Embed(
            cfg.num_positions, d, param_dtype=jnp.float32,
            embedding_init=logical(jax.nn.initializers.normal(std), ("positions", "embed")),
            rngs=rngs,
        )

    def __call__(self, pixels: jax.Array) -> jax.Array:
        """pixels [B, H, W, C] (channels last, CLIP-normalised) -> [B, 1 + patches, D]."""
        b, h, w, _ = pixels.shape
        if h != self.image_size or w != self.image_size:
            raise ValueError(f"image is {h}x{w}, the vision tower expects {self.image_size}x{self.image_size}")
        patches = self.patch_embedding(pixels.astype(self.dtype))
        patches = patches.reshape(b, -1, patches.shape[-1])  # row-major over the grid, as PyTorch's flatten(2)
        cls = jnp.broadcast_to(self.class_embedding[...].astype(patches.dtype), (b, 1, patches.shape[-1]))
        tokens = jnp.concatenate([cls, patches], axis=1)
        return tokens + self.position_embedding.embedding[...].astype(tokens.dtype)[None]


class VisionAttention(nnx.Module):
    def __init__(self, cfg: VisionConfig, dtype, rngs: nnx.Rngs, attention: str = "einsum"):
        d = cfg.hidden_size
        self.kernel = attention
        in_std = d**-0.5 * (2 * cfg.num_hidden_layers) ** -0.5
        self.num_heads = cfg.num_attention_heads
        self.k_proj = dense(d, d, ("embed", "heads"), rngs, std=in_std, dtype=dtype)
        self.v_proj = dense(d, d, ("embed", "heads"), rngs, std=in_std, dtype=dtype)
        self.q_proj = dense(d, d, ("embed", "heads"), rngs, std=in_std, dtype=dtype)
        self.out_proj = dense(d, d, ("heads", "embed"), rngs, std=d**-0.5, dtype=dtype)
        self.attn_dropout = Dropout(cfg.attention_dropout, rngs=rngs)  # on the weights, as CLIP does

    def __call__(self, x):
        q, k, v = (split_heads(p(x), self.num_heads) for p in (self.q_proj, self.k_proj, self.v_proj))
        out = dot_product_attention(q, k, v, mask=None, dropout=self.attn_dropout, kernel=self.kernel)
        return self.out_proj(out.reshape(*out.shape[:2], -1))


class VisionMLP(nnx.Module):
    def __init__(self, cfg: VisionConfig, dtype, rngs: nnx.Rngs):
        d, f = cfg.hidden_size, cfg.intermediate_size
        self.fc1 = dense(d, f, ("embed", "mlp"), rngs, std=(2 * d) ** -0.5, dtype=dtype)
        self.fc2 = dense(f, d, ("mlp", "embed"), rngs, std=d**-0.5 * (2 * cfg.num_hidden_layers) ** -0.5, dtype=dtype)

    def __call__(self, x):
        h = constrain(quick_gelu(self.fc1(x)), ("batch", "length", "act_mlp"))
        return self.fc2(h)


class VisionEncoderLayer(nnx.Module):
    def __init__(self, cfg: VisionConfig, dtype, rngs: nnx.Rngs, attention: str = "einsum"):
        self.self_attn = VisionAttention(cfg, dtype, rngs, attention)
        self.layer_norm1 = LayerNorm(cfg.hidden_size, cfg.layer_norm_eps, rngs)
        self.mlp = VisionMLP(cfg, dtype, rngs)
        self.layer_norm2 = LayerNorm(cfg.hidden_size, cfg.layer_norm_eps, rngs)

    def __call__(self, x):
        x = x + self.self_attn(self.layer_norm1(x))
        x = x + self.mlp(self.layer_norm2(x))
        return constrain(x, ACT)


def _encoder_step(layer, x, _per_layer):
    return layer(x), None


class VisionEncoder(nnx.Module):
    def __init__(self, cfg: VisionConfig, dtype, rngs: nnx.Rngs, *, scan_layers: bool = False, remat: bool = False,
                 remat_policy: str = "full", attention: str = "einsum"):
        self.scan_layers = scan_layers
        self.remat = remat
        self.remat_policy = remat_policy
        if scan_layers:
            self.layers = stack_blocks(lambda r: VisionEncoderLayer(cfg, dtype, r, attention), cfg.num_hidden_layers, rngs)
        else:
            self.layers = nnx.List([VisionEncoderLayer(cfg, dtype, rngs, attention) for _ in range(cfg.num_hidden_layers)])

    def __call__(self, x):
        if self.scan_layers:
            step = rematerialised(_encoder_step, self.remat, in_scan=True, policy=self.remat_policy)
            return scan_blocks(step, self.layers, x, None)[0]
        block = rematerialised(VisionEncoderLayer.__call__, self.remat, in_scan=False, policy=self.remat_policy)
        for layer in self.layers:
            x = block(layer, x)
        return x


class VisionTransformer(nnx.Module):
    def __init__(self, cfg: VisionConfig, dtype, rngs: nnx.Rngs, **layout):
        self.embeddings = VisionEmbeddings(cfg, dtype, rngs)
        self.pre_layrnorm = LayerNorm(cfg.hidden_size, cfg.layer_norm_eps, rngs)  # sic, the checkpoint's name
        self.encoder = VisionEncoder(cfg, dtype, rngs, **layout)
        self.post_layernorm = LayerNorm(cfg.hidden_size, cfg.layer_norm_eps, rngs)


class VisionModel(nnx.Module):
    def __init__(self, cfg: VisionConfig, dtype, rngs: nnx.Rngs, **layout):
        """`layout`: VisionEncoder's scan_layers, remat, remat_policy and attention."""
        self.model = VisionTransformer(cfg, dtype, rngs, **layout)

    def __call__(self, pixels: jax.Array) -> jax.Array:
        """Image features for the connector: post_layernorm on ALL tokens, then L2-normalised per token."""
        m = self.model
        x = constrain(m.pre_layrnorm(m.embeddings(pixels)), ACT)
        x = m.post_layernorm(m.encoder(x)).astype(jnp.float32)
        norm = jnp.sqrt(jnp.sum(x * x, axis=-1, keepdims=True))
        return x / jnp.maximum(norm, 1e-12)  # torch.nn.functional.normalize's eps
