"""The tower-label losses: the vision tower's feature at the target grasp's patch read out as a label of
the object there, its category (`tower_category_loss`) or its main colour (`tower_colour_loss`), with
the labels the synthetic scenes' metadata gives (the scene stream attaches each example's target
object's labels to it, each under its kind's name).

Why: on mosaics the object words must find their photo, and at the named object's patch the
stream-pretrained tower gives its category to a linear readout for only 31% of validation mosaics
(14 categories, `diagnostics.object_probe`): nothing asks the tower what an object is. These losses
ask it directly, which says whether supervising what the tower sees is enough for the words to
route (the phrase-patch loss asked through the words and did not move the routing).

No parameters: label c's logit is the unit feature's read along fixed seeded direction c of its
label set (orthogonal to the angle and offset reads, and the colour directions to the category
ones), over a temperature, as `phrase_patch` reads its space. Examples without a label (-1) or
without a finite target grasp take no part.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.models.patch_grid import grasp_cell_tokens
from kosmos_jax.sources.synthetic.objects import CATEGORIES, PALETTE
from kosmos_jax.train.loss import finite_example_tokens, offset_directions, tower_angle_directions
from kosmos_jax.train.phrase_patch import TEMPERATURE, shared_directions, unit

LABEL_NAMES = {"category": tuple(sorted(CATEGORIES)),  # a label is its name's place in its set
               "colour": tuple(sorted(PALETTE))}  # an object's main colour: the first of its colours
CATEGORY_NAMES = LABEL_NAMES["category"]
NO_LABEL = -1
_SEEDS = {"category": 4, "colour": 5}


def label_of(kind: str, name: str) -> int:
    """A synthetic object's label of `kind` ("category" or "colour"): its name's index in LABEL_NAMES[kind]."""
    if kind not in LABEL_NAMES:
        raise ValueError(f"unknown object label kind {kind!r}; known: {', '.join(LABEL_NAMES)}")
    names = LABEL_NAMES[kind]
    if name not in names:
        raise ValueError(f"unknown synthetic {kind} {name!r}; known: {', '.join(names)}")
    return names.index(name)


def label_directions(kind: str, width: int) -> np.ndarray:
    """[width, labels of kind]: one fixed direction a label, orthogonal to the angle and offset reads
    (and, for the colours, to the categories' directions, so the two losses do not read one another)."""
    others = 4 + (len(CATEGORY_NAMES) if kind == "colour" else 0)  # the angle and offset reads' 2 + 2
    if width < others + len(LABEL_NAMES[kind]):
        raise ValueError(f"the tower-{kind} loss reads {len(LABEL_NAMES[kind])} labels beside {others} other reads: "
                         f"it needs a vision tower at least {others + len(LABEL_NAMES[kind])} wide, got {width}")
    avoid = [tower_angle_directions(width), offset_directions(width)]
    if kind == "colour":
        avoid.append(label_directions("category", width))
    return shared_directions(width, len(LABEL_NAMES[kind]), seed=_SEEDS[kind], avoid=np.concatenate(avoid, axis=1))


def tower_label_sum(kind: str, features: jax.Array, labels: jax.Array, grasp: jax.Array, image_side: int,
                    loss_mask: jax.Array) -> jax.Array:
    """A tower-label loss as a sum: each example's cross-entropy of its target object's label of `kind`
    from the tower's feature at its grasp's patch, weighted by its loss tokens as the other auxiliary
    losses are. features [B, 1 + patches, Dv] (the class token first), labels [B] (NO_LABEL: none),
    grasp [B, 5] in pixels of an `image_side` view, loss_mask [B, T]."""
    weight = finite_example_tokens(loss_mask, grasp[:, :2]) * (labels >= 0)
    own = jnp.take_along_axis(jax.nn.log_softmax(label_logits(kind, features, grasp, image_side), axis=-1),
                              jnp.maximum(labels, 0)[:, None], axis=-1)[:, 0]
    return jnp.sum(jnp.where(weight > 0, -own * weight, 0.0))


def label_logits(kind: str, features: jax.Array, grasp: jax.Array, image_side: int) -> jax.Array:
    """[B, labels of kind]: the loss's logits, the unit feature at each grasp's patch read along
    `label_directions` over the temperature (a grasp that is not finite reads the first patch)."""
    patches = grasp_cell_tokens(features, jnp.nan_to_num(grasp[:, :2]) / image_side).astype(jnp.float32)
    return unit(patches) @ jnp.asarray(label_directions(kind, features.shape[-1])) / TEMPERATURE
