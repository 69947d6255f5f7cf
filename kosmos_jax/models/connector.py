"""`image_to_text_projection`: the latent-query resampler between the vision tower and the decoder.

Linear (vision width -> text width) on every image token; learned latent queries attend, in one
multi-head attention with biases, over [projected image tokens ; latent queries]. No residual, no
LayerNorm, no FFN.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.decoder import TextAttention
from kosmos_jax.models.layers import ACT, dense
from kosmos_jax.models.sharding import constrain


class ImageToTextProjection(nnx.Module):
    def __init__(self, cfg: Kosmos2Config, rngs: nnx.Rngs):
        d_text = cfg.text.embed_dim
        self.dense = dense(cfg.vision.hidden_size, d_text, ("embed", "heads"), rngs, std=cfg.connector_init_std,
                           dtype=cfg.dtype)
        self.latent_query = nnx.Param(jax.random.normal(rngs.params(), (cfg.latent_query_num, d_text)),
                                      logical_axes=("latents", "embed"))
        self.x_attn = TextAttention(cfg.text, cfg.dtype, rngs, inner_layernorm=False)

    def __call__(self, features: jax.Array) -> jax.Array:
        """features [B, 1 + patches, D_vision] -> image embeddings [B, latent_query_num, D_text] (float32)."""
        tokens = self.dense(features)
        queries = jnp.broadcast_to(self.latent_query[...].astype(tokens.dtype), (tokens.shape[0], *self.latent_query.shape))
        keys = jnp.concatenate([tokens, queries], axis=1)
        out, _ = self.x_attn(queries, mask=None, kv_input=keys)
        return constrain(out.astype(jnp.float32), ACT)
