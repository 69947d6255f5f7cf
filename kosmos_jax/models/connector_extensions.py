"""Options of the connector for models trained from scratch (not KOSMOS-2's; `Kosmos2Config.EXTENSION_FIELDS`).

- `connector_grid_code` > 0: the projected tokens are centred on the image's mean patch token and
  each patch token gets that many times a fixed sin-cos code of its grid cell (`patch_grid.grid_code`),
  so a query that attends to one patch carries that patch's position in its slot.
- `connector_instruction`: every latent query also gets a zero-initialised dense layer of the
  instruction's bag of words (`instruction_bag`), so the connector can look for the object an
  instruction names (on a mosaic, one photo of four).

`projection(cfg, rngs)` builds KOSMOS-2's connector when neither is set, so a model without them has
exactly KOSMOS-2's modules.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.connector import ImageToTextProjection
from kosmos_jax.models.layers import dense
from kosmos_jax.models.patch_grid import grid_code


class ExtendedProjection(ImageToTextProjection):
    """KOSMOS-2's connector with the grid code and/or the instruction's queries (same parameter paths,
    plus `instruction` when it reads one)."""

    def __init__(self, cfg: Kosmos2Config, rngs: nnx.Rngs):
        super().__init__(cfg, rngs)
        d_text = cfg.text.embed_dim
        self.grid_code = cfg.connector_grid_code
        self.instruction = (dense(d_text, d_text, ("embed", "heads"), rngs, std=0.0, dtype=cfg.dtype)
                            if cfg.connector_instruction else None)

    def image_tokens(self, features: jax.Array) -> jax.Array:
        tokens = super().image_tokens(features)
        if not self.grid_code:
            return tokens
        tokens = tokens - tokens[:, 1:].mean(axis=1, keepdims=True)
        return tokens + self.grid_code * grid_code(features.shape[1] - 1, tokens.shape[-1]).astype(tokens.dtype)

    def latent_queries(self, batch: int, dtype, instruction: jax.Array | None = None) -> jax.Array:
        if self.instruction is None:
            return super().latent_queries(batch, dtype, instruction)
        if instruction is None:
            raise ValueError("this connector reads the instruction (connector_instruction): give the prompt's "
                             "bag of words (Kosmos2.instruction_bag)")
        return super().latent_queries(batch, dtype) + self.instruction(instruction.astype(dtype))[:, None, :]


def projection(cfg: Kosmos2Config, rngs: nnx.Rngs) -> ImageToTextProjection:
    """The connector of `cfg`: KOSMOS-2's, or its extension when a from-scratch option is set."""
    extended = cfg.connector_grid_code or cfg.connector_instruction
    return (ExtendedProjection if extended else ImageToTextProjection)(cfg, rngs)


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
