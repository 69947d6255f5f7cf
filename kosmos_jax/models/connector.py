"""`image_to_text_projection`: the latent-query resampler between the vision tower and the decoder.

Linear (vision width -> text width) on every image token; learned latent queries attend, in one
multi-head attention with biases, over [projected image tokens ; latent queries]. No residual, no
LayerNorm, no FFN.

With `connector_grid_code` > 0 (not KOSMOS-2; for models trained from scratch) the projected tokens
are centred on the image's mean patch token and each patch token gets a fixed sin-cos code of its
grid cell, so a query that attends to one patch carries that patch's position in its slot.
`pointing_log_probs` gives the attention's log-probabilities, for a loss that teaches the queries
where to look (`train.pointing_loss`).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
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
        self.grid_code = cfg.connector_grid_code
        self.instruction = (dense(d_text, d_text, ("embed", "heads"), rngs, std=0.0, dtype=cfg.dtype)
                            if cfg.connector_instruction else None)

    def queries_and_keys(self, features: jax.Array, instruction: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
        """features [B, 1 + patches, D_vision] (and, for a connector that reads it, the instruction's bag
        [B, D_text], `instruction_bag`) -> latent queries [B, Q, D_text], keys [B, 1 + patches + Q, D_text]."""
        tokens = self.dense(features)
        if self.grid_code:
            tokens = tokens - tokens[:, 1:].mean(axis=1, keepdims=True)
            tokens = tokens + self.grid_code * grid_code(features.shape[1] - 1, tokens.shape[-1]).astype(tokens.dtype)
        queries = jnp.broadcast_to(self.latent_query[...].astype(tokens.dtype), (tokens.shape[0], *self.latent_query.shape))
        if self.instruction is not None:
            if instruction is None:
                raise ValueError("this connector reads the instruction (connector_instruction): give the prompt's "
                                 "bag of words (Kosmos2.instruction_bag)")
            queries = queries + self.instruction(instruction.astype(tokens.dtype))[:, None, :]
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


def instruction_mean(table: jax.Array, input_ids: jax.Array, attention_mask: jax.Array, image_mask: jax.Array,
                     answer_mask: jax.Array | None = None) -> jax.Array:
    """[B, D] the mean embedding (rows of `table` [V, D]) of each row's real tokens after its image slots
    and their </image>, and before its first answer token where `answer_mask` [B, T] marks the answer
    (a training sequence; a prompt holds none); zeros for a row without such tokens (no instruction)."""
    positions = jnp.arange(input_ids.shape[1])[None, :]
    last_slot = input_ids.shape[1] - 1 - jnp.argmax(image_mask[:, ::-1], axis=1)
    chosen = (positions > last_slot[:, None] + 1) & attention_mask.astype(bool)
    if answer_mask is not None:
        first_answer = jnp.where(answer_mask.any(axis=1), jnp.argmax(answer_mask, axis=1), input_ids.shape[1])
        chosen = chosen & (positions < first_answer[:, None])
    rows = jnp.take(table, input_ids, axis=0).astype(jnp.float32)
    return jnp.sum(jnp.where(chosen[..., None], rows, 0.0), axis=1) / jnp.maximum(jnp.sum(chosen, axis=1, keepdims=True), 1)


def instruction_bag(table: jax.Array, input_ids: jax.Array, attention_mask: jax.Array, image_mask: jax.Array,
                    answer_mask: jax.Array | None = None) -> jax.Array:
    """`instruction_mean` scaled to a root mean square of 1 (zeros stay zeros): what the connector reads.
    Unscaled, the mean of embeddings started at std 0.02 moved the queries (norm ~11) by about 4% after
    1,500 steps (results/pretrain/README.md)."""
    mean = instruction_mean(table, input_ids, attention_mask, image_mask, answer_mask)
    return mean * jax.lax.rsqrt(jnp.mean(mean ** 2, axis=-1, keepdims=True) + 1e-12)


def grid_side(patches: int) -> int:
    """The side of the square patch grid that `patches` tokens form (row-major, as the vision tower lays them out)."""
    side = math.isqrt(patches)
    if side * side != patches:
        raise ValueError(f"{patches} patches do not form a square grid")
    return side


def cell_index(centres: jax.Array, side: int) -> jax.Array:
    """[B, 2] centres (x, y) in units of the view's side -> [B] row-major index of the patch holding each."""
    cell = jnp.clip(jnp.floor(centres * side), 0, side - 1).astype(jnp.int32)
    return cell[:, 1] * side + cell[:, 0]


def grasp_cell_tokens(tokens: jax.Array, centres: jax.Array) -> jax.Array:
    """tokens [B, 1 + patches, D] (the class token first), centres [B, 2] in units of the view's side ->
    [B, D] each example's token of the patch that holds its centre."""
    cell = 1 + cell_index(centres, grid_side(tokens.shape[1] - 1))
    return jnp.take_along_axis(tokens, cell[:, None, None], axis=1)[:, 0]


def cell_centre(index: jax.Array, side: int) -> jax.Array:
    """[B] row-major patch indices -> [B, 2] their centres (x, y) in units of the view's side."""
    return (jnp.stack([index % side, index // side], axis=-1) + 0.5) / side


def grid_code(patches: int, width: int) -> jnp.ndarray:
    """[1 + patches, width]: a sin-cos code of each patch's cell (x then y) of the square grid, zeros
    for the class token; frequencies from one to width/8 periods across the grid."""
    side = grid_side(patches)
    if width % 4:
        raise ValueError(f"a grid code needs a width divisible by 4, got {width}")
    frequencies = 100.0 ** -(np.arange(width // 4) / (width // 4))
    cells = (np.arange(side) + 0.5) / side * 2 * np.pi
    y, x = (np.repeat(cells, side), np.tile(cells, side))
    angles_x, angles_y = x[:, None] * frequencies, y[:, None] * frequencies
    code = np.concatenate([np.sin(angles_x), np.cos(angles_x), np.sin(angles_y), np.cos(angles_y)], axis=1)
    return jnp.asarray(np.concatenate([np.zeros((1, width)), code]), jnp.float32)
