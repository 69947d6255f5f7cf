"""The phrase-patch loss: an instruction's words and the vision tower's feature at the patch of the
grasp it asks for, matched against the batch's other examples (a contrastive loss, as CLIP matches
captions and images, here a phrase and a region as KOSMOS-2's grounding does).

Why: on mosaics the object words (name, colour, shape, purpose, strategy) must be matched to what
the tower sees; at the named object's patch the stream-pretrained tower gives its category to a
linear readout for 31% of validation mosaics (14 categories, `diagnostics.object_probe`), and no
loss asks it for more. This one does, and it moves the words' embeddings toward what they name.

No parameters: both sides are read along fixed, seeded directions (as `loss.tower_angle_directions`
reads the angle), the tower's orthogonal to the angle and offset reads. Words: the mean embedding
of the instruction's tokens (`connector_extensions.instruction_mean`), centred over the examples
that count, so the template words every instruction shares drop out. Examples without an
instruction (NON) or without a finite target grasp take no part. With microbatches the other
examples are those of the microbatch.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.models.connector_extensions import instruction_mean
from kosmos_jax.models.patch_grid import grasp_cell_tokens
from kosmos_jax.train.loss import finite_example_tokens, offset_directions, tower_angle_directions

PHRASE_DIMENSIONS = 32  # at most: the shared space's size (the tower's width less the angle and offset reads)
TEMPERATURE = 0.1


def shared_directions(width: int, dimensions: int, seed: int, avoid: np.ndarray | None = None) -> np.ndarray:
    """[width, dimensions] fixed orthonormal directions (seeded), orthogonal to the columns of `avoid`."""
    taken = 0 if avoid is None else avoid.shape[1]
    draws = np.random.default_rng(seed).normal(size=(width, dimensions))
    basis, _ = np.linalg.qr(draws if avoid is None else np.concatenate([avoid, draws], axis=1))
    return basis[:, taken:taken + dimensions].astype(np.float32)


def phrase_dimensions(vision_width: int, text_width: int) -> int:
    """The shared space's size for a tower and a decoder of these widths (the angle and offset reads kept apart)."""
    size = min(PHRASE_DIMENSIONS, vision_width - 4, text_width)
    if size < 2:
        raise ValueError(f"the phrase-patch loss needs a tower wider than 5 and a decoder wider than 1, got "
                         f"{vision_width} and {text_width}")
    return size


def unit(vectors: jax.Array) -> jax.Array:
    return vectors / jnp.maximum(jnp.linalg.norm(vectors, axis=-1, keepdims=True), 1e-6)


def phrase_patch_sum(features: jax.Array, table: jax.Array, tokens: jax.Array, attention_mask: jax.Array,
                     image_mask: jax.Array, loss_mask: jax.Array, grasp: jax.Array, image_side: int) -> jax.Array:
    """The phrase-patch loss as a sum: for each example that counts, the cross-entropy of finding its own
    patch among the batch's patches from its words, and its own words from its patch (the mean of the
    two), weighted by its loss tokens as the other auxiliary losses are.

    features [B, 1 + patches, Dv] (the tower's tokens, the class token first), table [V, Dt] (the
    token embeddings), tokens/attention_mask/image_mask/loss_mask [B, T], grasp [B, 5] in pixels of
    an `image_side` view."""
    vision_width, text_width = features.shape[-1], table.shape[-1]
    size = phrase_dimensions(vision_width, text_width)
    avoid = np.concatenate([tower_angle_directions(vision_width), offset_directions(vision_width)], axis=1)
    patch_read = shared_directions(vision_width, size, seed=2, avoid=avoid)
    word_read = shared_directions(text_width, size, seed=3)
    words = instruction_mean(table, tokens, attention_mask, image_mask, loss_mask)
    weight = finite_example_tokens(loss_mask, grasp[:, :2]) * jnp.any(words != 0, axis=-1)
    counts = weight > 0
    centre = jnp.sum(jnp.where(counts[:, None], words, 0.0), axis=0) / jnp.maximum(jnp.sum(counts), 1)
    patches = grasp_cell_tokens(features, jnp.nan_to_num(grasp[:, :2]) / image_side).astype(jnp.float32)
    similarity = unit((words - centre) @ jnp.asarray(word_read)) @ unit(patches @ jnp.asarray(patch_read)).T
    logits = jnp.where(counts[None, :] & counts[:, None], similarity / TEMPERATURE, -1e9)
    own = jnp.arange(logits.shape[0])
    by_words = -jax.nn.log_softmax(logits, axis=1)[own, own]
    by_patch = -jax.nn.log_softmax(logits, axis=0)[own, own]
    return jnp.sum(jnp.where(counts, 0.5 * (by_words + by_patch), 0.0) * weight)
