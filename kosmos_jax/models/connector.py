"""`image_to_text_projection`: KOSMOS-2's latent-query resampler between the vision tower and the decoder.

Linear (vision width -> text width) on every image token; learned latent queries attend, in one
multi-head attention with biases, over [projected image tokens ; latent queries]. No residual, no
LayerNorm, no FFN. `pointing_log_probs` gives the attention's log-probabilities, for a loss that
teaches the queries where to look (`train.pointing_loss`).

The options of models trained from scratch (a grid code on the patch tokens, queries that read the
instruction) extend this class in `connector_extensions.py`; this one is KOSMOS-2's alone.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.decoder import TextAttention
from kosmos_jax.models.layers import ACT, attention_scores, dense, split_heads
from kosmos_jax.models.sharding import constrain


class ImageToTextProjection(nnx.Module):
    def __init__(self, cfg: Kosmos2Config, rngs: nnx.Rngs):
        d_text = cfg.text.embed_dim
        self.dense = dense(cfg.vision.hidden_size, d_text, ("embed", "heads"), rngs, std=cfg.connector_init_std,
                           dtype=cfg.dtype)
        self.latent_query = nnx.Param(jax.random.normal(rngs.params(), (cfg.latent_query_num, d_text)),
                                      logical_axes=("latents", "embed"))
        self.x_attn = TextAttention(cfg.text, cfg.dtype, rngs, inner_layernorm=False)

    def image_tokens(self, features: jax.Array) -> jax.Array:
        """features [B, 1 + patches, D_vision] -> the projected tokens [B, 1 + patches, D_text]."""
        return self.dense(features)

    def latent_queries(self, batch: int, dtype, instruction: jax.Array | None = None) -> jax.Array:
        """[B, Q, D_text]: the same learned queries for every example (KOSMOS-2 reads no instruction)."""
        if instruction is not None:
            raise ValueError("KOSMOS-2's connector reads no instruction (that is model.connector_instruction)")
        return jnp.broadcast_to(self.latent_query[...].astype(dtype), (batch, *self.latent_query.shape))

    def queries_and_keys(self, features: jax.Array, instruction: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
        """features [B, 1 + patches, D_vision] (and, for a connector that reads it, the instruction's bag
        [B, D_text]) -> latent queries [B, Q, D_text], keys [B, 1 + patches + Q, D_text]."""
        tokens = self.image_tokens(features)
        queries = self.latent_queries(tokens.shape[0], tokens.dtype, instruction)
        return queries, jnp.concatenate([tokens, queries], axis=1)

    def __call__(self, features: jax.Array, instruction: jax.Array | None = None) -> jax.Array:
        """features [B, 1 + patches, D_vision] -> image embeddings [B, latent_query_num, D_text] (float32)."""
        queries, keys = self.queries_and_keys(features, instruction)
        out, _ = self.x_attn(queries, mask=None, kv_input=keys)
        return constrain(out.astype(jnp.float32), ACT)

    def pointing_log_probs(self, features: jax.Array, instruction: jax.Array | None = None) -> jax.Array:
        """[B, heads, Q, 1 + patches + Q] float32: where each head of each latent query looks (log-softmax)."""
        queries, keys = self.queries_and_keys(features, instruction)
        attention = self.x_attn
        q, k = (split_heads(project(x), attention.num_heads) for project, x in ((attention.q_proj, queries), (attention.k_proj, keys)))
        return jax.nn.log_softmax(attention_scores(q, k), axis=-1)
