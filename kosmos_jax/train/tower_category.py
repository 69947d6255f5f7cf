"""The tower-category loss: the vision tower's feature at the target grasp's patch read out as the
category of the object there, with the labels the synthetic scenes' metadata gives (the scene stream
attaches each example's target object's category to it as `category`).

Why: on mosaics the object words must find their photo, and at the named object's patch the
stream-pretrained tower gives its category to a linear readout for only 31% of validation mosaics
(14 categories, `diagnostics.object_probe`): nothing asks the tower what an object is. This loss
asks it directly, which says whether supervising what the tower sees is enough for the words to
route (the phrase-patch loss asked through the words and did not move the routing).

No parameters: category c's logit is the unit feature's read along fixed seeded direction c
(orthogonal to the angle and offset reads), over a temperature, as `phrase_patch` reads its space.
Examples without a category (-1) or without a finite target grasp take no part.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.models.patch_grid import grasp_cell_tokens
from kosmos_jax.sources.synthetic.objects import CATEGORIES
from kosmos_jax.train.loss import finite_example_tokens, offset_directions, tower_angle_directions
from kosmos_jax.train.phrase_patch import TEMPERATURE, shared_directions, unit

CATEGORY_NAMES = tuple(sorted(CATEGORIES))  # a category's label is its place here
NO_CATEGORY = -1


def category_label(name: str) -> int:
    """A synthetic category's label (its index in CATEGORY_NAMES)."""
    if name not in CATEGORY_NAMES:
        raise ValueError(f"unknown synthetic category {name!r}; known: {', '.join(CATEGORY_NAMES)}")
    return CATEGORY_NAMES.index(name)


def category_directions(width: int) -> np.ndarray:
    """[width, categories]: one fixed direction a category, orthogonal to the angle and offset reads."""
    if width < len(CATEGORY_NAMES) + 4:
        raise ValueError(f"the tower-category loss reads {len(CATEGORY_NAMES)} categories beside the angle and "
                         f"offset reads: it needs a vision tower at least {len(CATEGORY_NAMES) + 4} wide, got {width}")
    avoid = np.concatenate([tower_angle_directions(width), offset_directions(width)], axis=1)
    return shared_directions(width, len(CATEGORY_NAMES), seed=4, avoid=avoid)


def tower_category_sum(features: jax.Array, category: jax.Array, grasp: jax.Array, image_side: int,
                       loss_mask: jax.Array) -> jax.Array:
    """The tower-category loss as a sum: each example's cross-entropy of its target object's category
    from the tower's feature at its grasp's patch, weighted by its loss tokens as the other auxiliary
    losses are. features [B, 1 + patches, Dv] (the class token first), category [B] (NO_CATEGORY: none),
    grasp [B, 5] in pixels of an `image_side` view, loss_mask [B, T]."""
    weight = finite_example_tokens(loss_mask, grasp[:, :2]) * (category >= 0)
    own = jnp.take_along_axis(jax.nn.log_softmax(category_logits(features, grasp, image_side), axis=-1),
                              jnp.maximum(category, 0)[:, None], axis=-1)[:, 0]
    return jnp.sum(jnp.where(weight > 0, -own * weight, 0.0))


def category_logits(features: jax.Array, grasp: jax.Array, image_side: int) -> jax.Array:
    """[B, categories]: the loss's logits, the unit feature at each grasp's patch read along
    `category_directions` over the temperature (a grasp that is not finite reads the first patch)."""
    patches = grasp_cell_tokens(features, jnp.nan_to_num(grasp[:, :2]) / image_side).astype(jnp.float32)
    return unit(patches) @ jnp.asarray(category_directions(features.shape[-1])) / TEMPERATURE
