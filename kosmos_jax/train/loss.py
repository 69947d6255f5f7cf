"""Next-token cross-entropy and accuracy as sums, so any split of a batch adds up to the whole.

`loss_mask` marks the TARGET tokens themselves (text/layout.py: "the label at position i is
tokens[i]; the train step shifts"): the logits at position t predict tokens[t + 1], and that
prediction counts when loss_mask[t + 1]. Position 0 (<s>) is never a target. The mean is taken by
the caller once, over the loss tokens of the whole global batch.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax

from kosmos_jax import geometry
from kosmos_jax.models.patch_grid import cell_centre, cell_index, grasp_cell_tokens, grid_side


def token_sums(logits: jax.Array, tokens: jax.Array, loss_mask: jax.Array) -> dict[str, jax.Array]:
    """logits [B, T, V], tokens int [B, T], loss_mask bool [B, T] ->
    {"loss_sum": float32, "correct": int32, "tokens": int32} over the marked targets."""
    predicting = logits[:, :-1].astype(jnp.float32)
    targets = tokens[:, 1:]
    counted = loss_mask[:, 1:]
    nll = optax.softmax_cross_entropy_with_integer_labels(predicting, targets)
    hit = jnp.argmax(predicting, axis=-1) == targets
    return {
        "loss_sum": jnp.sum(jnp.where(counted, nll, 0.0)),
        "correct": jnp.sum(hit & counted, dtype=jnp.int32),
        "tokens": jnp.sum(counted, dtype=jnp.int32),
    }


def circular_kernel(bins: int, width: float) -> np.ndarray:
    """[bins, bins] float32: row k is a Gaussian of `width` bins around bin k, wrapped (bin 0 lies next
    to bin bins-1) and normalised to sum 1; the soft target of an angle token (a circular smooth label)."""
    offsets = np.arange(bins)[None, :] - np.arange(bins)[:, None]
    distance = np.minimum(np.abs(offsets), bins - np.abs(offsets))
    kernel = np.exp(-0.5 * (distance / width) ** 2)
    return (kernel / kernel.sum(axis=1, keepdims=True)).astype(np.float32)


def smoothed_angle_sum(logits: jax.Array, tokens: jax.Array, loss_mask: jax.Array, angle_ids: jax.Array,
                       kernel: jax.Array) -> jax.Array:
    """The training objective with circular smooth labels on angle tokens, as a sum over the marked targets:
    a target that is angle bin k (tokens[t] == angle_ids[k]) is scored by the cross-entropy against
    kernel[k] spread over the angle tokens, so a_254 and a_1 count as near misses of a_0; every other
    target by the usual cross-entropy. angle_ids int [bins]: the token id of each bin, in order."""
    log_p = jax.nn.log_softmax(logits[:, :-1].astype(jnp.float32), axis=-1)
    targets = tokens[:, 1:]
    counted = loss_mask[:, 1:]
    bin_of = jnp.full((logits.shape[-1],), -1, jnp.int32).at[angle_ids].set(jnp.arange(angle_ids.shape[0]))
    target_bin = bin_of[targets]
    hard = -jnp.take_along_axis(log_p, targets[..., None], axis=-1)[..., 0]
    soft = -jnp.sum(kernel[jnp.maximum(target_bin, 0)] * log_p[..., angle_ids], axis=-1)
    return jnp.sum(jnp.where(counted, jnp.where(target_bin >= 0, soft, hard), 0.0))


def finite_example_tokens(loss_mask: jax.Array, required: jax.Array) -> jax.Array:
    """[B] each example's loss-token count where its `required` grasp fields [B, k] are all finite, else 0:
    an auxiliary loss's weight per example, so that its sum divided by the batch's token count, like
    the text loss, is a per-token mean, and examples without a target grasp add nothing."""
    return jnp.where(jnp.isfinite(required).all(-1), jnp.sum(loss_mask[:, 1:], axis=-1), 0)


POINTING_TARGETS = ("cell", "bilinear", "identity")


def pointing_weights(centres: jax.Array, side: int, target: str = "cell") -> jax.Array:
    """[B, side * side] where the pointing loss asks each query to look, for centres [B, 2] (x, y) in units
    of the view's side: "cell" all on the patch that holds the centre; "bilinear" shared between the (up to)
    four patches whose centres surround it, in proportion to how near it lies to each (a patch's weight
    is 1 at its own centre), so that a query that looks as asked carries the grid code of the centre's
    own position between cells, not only of its cell."""
    if target == "cell":
        return jax.nn.one_hot(cell_index(centres, side), side * side, dtype=jnp.float32)
    if target != "bilinear":
        raise ValueError(f"pointing target must be one of {POINTING_TARGETS}, got {target!r}")
    # in units of cells, measured from the first cell's centre; clamped so the border cells take it all
    position = jnp.clip(centres * side - 0.5, 0.0, side - 1.0)
    low = jnp.clip(jnp.floor(position), 0, max(side - 2, 0)).astype(jnp.int32)
    fraction = position - low
    along = lambda axis: (jax.nn.one_hot(low[:, axis], side) * (1 - fraction[:, axis, None])
                          + jax.nn.one_hot(low[:, axis] + 1, side) * fraction[:, axis, None])
    return (along(1)[:, :, None] * along(0)[:, None, :]).reshape(centres.shape[0], side * side)  # row-major: y, x


def pointing_sum(log_probs: jax.Array, grasp: jax.Array, image_side: int, loss_mask: jax.Array,
                 queries: int = 0, target: str = "cell") -> jax.Array:
    """The connector's pointing loss as a sum: for each example, the cross-entropy of every head of every
    latent query against where `pointing_weights` asks it to look for the target grasp's centre
    (log_probs [B, H, Q, 1 + patches + Q], keys in the connector's order, the class token first; with
    target "cell", minus the log-probability of the patch that holds the centre), weighted by the
    example's loss tokens so that, divided by the batch's token count like the text loss, it is a
    per-token mean. `queries` > 0 points only the first that many latent queries and leaves the others
    free to look elsewhere."""
    side = grid_side(log_probs.shape[-1] - 1 - log_probs.shape[2])
    if target == "identity":
        return identity_pointing_sum(log_probs, side, loss_mask)
    if queries:
        log_probs = log_probs[:, :, :queries]
    weights = pointing_weights(jnp.nan_to_num(grasp[:, :2]) / image_side, side, target)
    patch_log_probs = log_probs[..., 1:1 + side * side].mean(axis=(1, 2))
    cross_entropy = -jnp.sum(weights * patch_log_probs, axis=-1)
    return jnp.sum(cross_entropy * finite_example_tokens(loss_mask, grasp[:, :2]))


def identity_pointing_sum(log_probs: jax.Array, side: int, loss_mask: jax.Array) -> jax.Array:
    """The pointing loss with target "identity" as a sum: latent query q asked to look at patch q (row-major),
    whatever the instruction, so that slot q carries patch q's content and grid code and the decoder
    gets every object of the view with its place, instead of 64 slots pointed at the one grasp that
    an instruction it never sees names (on a mosaic, one of four). Needs as many queries as patches;
    weighted by each example's loss tokens, as the other targets are."""
    queries, patches = log_probs.shape[2], side * side
    if queries != patches:
        raise ValueError(f"pointing_target 'identity' needs one latent query a patch: {queries} queries, {patches} patches")
    patch_log_probs = log_probs[..., 1:1 + patches].mean(axis=1)  # [B, Q, patches], over heads
    cross_entropy = -jnp.trace(patch_log_probs, axis1=1, axis2=2) / queries
    return jnp.sum(cross_entropy * jnp.sum(loss_mask[:, 1:], axis=-1))


def image_slot_states(hidden: jax.Array, image_mask: jax.Array, slots: int) -> jax.Array:
    """hidden [B, T, D] -> [B, slots, D]: the states at the image slots, which image_mask [B, T] marks contiguously."""
    positions = jnp.argmax(image_mask, axis=1)[:, None] + jnp.arange(slots)[None, :]
    return jnp.take_along_axis(hidden, positions[..., None], axis=1)


def answer_pointing_sum(hidden: jax.Array, image_mask: jax.Array, slots: int, grasp: jax.Array, image_side: int,
                        loss_mask: jax.Array) -> jax.Array:
    """The answer-pointing loss as a sum: at every position that predicts a loss token, the decoder's
    final hidden state (hidden [B, T, D]) scores each of the `slots` image slots' final hidden states by
    dot product over sqrt(D) (no parameters), and the cross-entropy of those scores against the slot of
    the patch that holds the target grasp's centre. Unlike the connector's pointing, the decoder has
    read the instruction, so this asks it to find the object an instruction names (on a mosaic, one of
    four). The slots must be the patches in row-major order (pointing_target "identity"); image_mask
    [B, T] marks them, contiguous. Each counted position adds its cross-entropy, as the text loss does;
    an example without a target grasp adds nothing."""
    slot_states = image_slot_states(hidden, image_mask, slots)
    scores = jnp.einsum("btd,bsd->bts", hidden[:, :-1], slot_states) / jnp.sqrt(jnp.float32(hidden.shape[-1]))
    target = cell_index(jnp.nan_to_num(grasp[:, :2]) / image_side, grid_side(slots))
    nll = -jnp.take_along_axis(jax.nn.log_softmax(scores, axis=-1), target[:, None, None], axis=-1)[..., 0]
    counted = loss_mask[:, 1:] & jnp.isfinite(grasp[:, :2]).all(-1)[:, None]
    return jnp.sum(jnp.where(counted, nll, 0.0))


def patch_angle_sum(patch_tokens: jax.Array, angle_rows: jax.Array, grasp: jax.Array, image_side: int,
                    loss_mask: jax.Array) -> jax.Array:
    """The patch-angle loss as a sum: the image token of the patch that holds the target grasp's centre
    (patch_tokens [B, 1 + patches, D], the class token first, as the connector projects them) scored
    against each angle token's row (angle_rows [bins, D], bin order) by dot product, and the
    cross-entropy of those scores against the grasp's angle bin. It asks the vision tower for the
    orientation at the grasp's patch in the form the decoder answers with; weighted by each example's
    loss tokens as `pointing_sum` is."""
    picked = grasp_cell_tokens(patch_tokens, grasp[:, :2] / image_side).astype(jnp.float32)
    log_p = jax.nn.log_softmax(picked @ angle_rows.astype(jnp.float32).T, axis=-1)
    target = geometry.encode_angle(jnp.nan_to_num(grasp[:, 4]))
    nll = -jnp.take_along_axis(log_p, target[:, None], axis=-1)[:, 0]
    return jnp.sum(nll * finite_example_tokens(loss_mask, grasp))


TOWER_ANGLE_RADIUS = 0.5  # of the unit-norm feature, the share the orientation is asked to take


def tower_angle_directions(width: int) -> np.ndarray:
    """[width, 2]: a fixed orthonormal pair, the read-out of `tower_angle_sum` (no parameters to learn
    or export; seeded, so every run and process reads the same pair)."""
    directions, _ = np.linalg.qr(np.random.default_rng(0).normal(size=(width, 2)))
    return directions.astype(np.float32)


def read_error(vectors: jax.Array, directions: np.ndarray, target: jax.Array) -> jax.Array:
    """vectors [B, ..., D], directions [D, 2], target [B, 2] -> [B, ...]: the squared distance of each
    vector's read along the fixed pair from its example's target."""
    read = vectors.astype(jnp.float32) @ jnp.asarray(directions)
    target = target.reshape(target.shape[:1] + (1,) * (read.ndim - 2) + target.shape[1:])
    return jnp.sum((read - target) ** 2, axis=-1)


def unit_slots(image_embeds: jax.Array) -> jax.Array:
    """[B, Q, D] the connector's slots scaled to unit norm (float32), as the slot losses read them."""
    slots = image_embeds.astype(jnp.float32)
    return slots / jnp.maximum(jnp.linalg.norm(slots, axis=-1, keepdims=True), 1e-6)


def doubled_angle_error(vectors: jax.Array, theta: jax.Array) -> jax.Array:
    """vectors [B, ..., D] (unit norm), theta [B] -> [B, ...]: `read_error` along `tower_angle_directions`
    from TOWER_ANGLE_RADIUS * (cos 2theta, sin 2theta) (2theta: a grasp and its half-turn are one)."""
    target = TOWER_ANGLE_RADIUS * jnp.stack([jnp.cos(2 * theta), jnp.sin(2 * theta)], axis=-1)
    return read_error(vectors, tower_angle_directions(vectors.shape[-1]), target)


def tower_angle_sum(features: jax.Array, grasp: jax.Array, image_side: int, loss_mask: jax.Array) -> jax.Array:
    """The tower-angle loss as a sum: the vision tower's feature at the patch that holds the target
    grasp's centre (features [B, 1 + patches, D], unit-norm tokens, the class token first) scored by
    `doubled_angle_error`. It asks the tower for the orientation at the grasp in a smooth, periodic
    form, which a 256-way answer does not give it; weighted by each example's loss tokens as
    `pointing_sum` is."""
    picked = grasp_cell_tokens(features, grasp[:, :2] / image_side)
    error = doubled_angle_error(picked, jnp.nan_to_num(grasp[:, 4]))
    return jnp.sum(error * finite_example_tokens(loss_mask, grasp))


def slot_angle_sum(image_embeds: jax.Array, grasp: jax.Array, loss_mask: jax.Array) -> jax.Array:
    """The slot-angle loss as a sum: every image slot the decoder reads (image_embeds [B, Q, D], the
    connector's output), scaled to unit norm and scored by `doubled_angle_error`, averaged over the
    slots. The connector's slots carry the grasp's cell in most of their variance and its angle in
    a fraction of a percent even when the tower holds it (results/angle_study, third round); this
    asks for the angle as a share of the slot itself. Weighted by each example's loss tokens as
    `pointing_sum` is."""
    error = doubled_angle_error(unit_slots(image_embeds), jnp.nan_to_num(grasp[:, 4])).mean(axis=1)
    return jnp.sum(error * finite_example_tokens(loss_mask, grasp))


OFFSET_RADIUS = 0.35  # of the unit-norm feature, the most each axis of the offset is asked to take


def offset_directions(width: int) -> np.ndarray:
    """[width, 2]: a fixed orthonormal pair orthogonal to `tower_angle_directions`, the read-out of the
    offset losses (seeded and parameter-free like that pair), so the angle and the offset never share a read."""
    if width < 4:
        raise ValueError(f"the offset read needs a width of at least 4, got {width}")
    both = np.concatenate([tower_angle_directions(width), np.random.default_rng(1).normal(size=(width, 2))], axis=1)
    directions, _ = np.linalg.qr(both)
    return directions[:, 2:].astype(np.float32)


def cell_offset(centres: jax.Array, side: int) -> jax.Array:
    """[B, 2] centres (x, y) in units of the view's side -> [B, 2] where each lies in the patch that holds
    it, from -1 (its left or top edge) through 0 (its centre) to 1; the border patches' outer side clamped."""
    from_centre = centres - cell_centre(cell_index(centres, side), side)
    return jnp.clip(2 * side * from_centre, -1.0, 1.0)


def offset_error(vectors: jax.Array, centres: jax.Array, side: int) -> jax.Array:
    """vectors [B, ..., D] (unit norm), centres [B, 2] in units of the view's side -> [B, ...]: the squared
    distance of each vector's read along `offset_directions` from OFFSET_RADIUS * `cell_offset`."""
    return read_error(vectors, offset_directions(vectors.shape[-1]), OFFSET_RADIUS * cell_offset(centres, side))


def tower_offset_sum(features: jax.Array, grasp: jax.Array, image_side: int, loss_mask: jax.Array) -> jax.Array:
    """The tower-offset loss as a sum: the vision tower's feature at the patch that holds the target grasp's
    centre (features as `tower_angle_sum` takes them) scored by `offset_error`: it asks the tower where
    in that patch the centre lies, which the grid code of its cell cannot say (a patch is 28 px of a
    224 px view; a grasp's jaws are about 14 px apart). Weighted by each example's loss tokens as
    `pointing_sum` is."""
    centres = jnp.nan_to_num(grasp[:, :2]) / image_side
    picked = grasp_cell_tokens(features, centres)
    error = offset_error(picked, centres, grid_side(features.shape[1] - 1))
    return jnp.sum(error * finite_example_tokens(loss_mask, grasp[:, :2]))


def slot_offset_sum(image_embeds: jax.Array, grasp: jax.Array, image_side: int, side: int,
                    loss_mask: jax.Array) -> jax.Array:
    """The slot-offset loss as a sum: every image slot (image_embeds [B, Q, D]), scaled to unit norm and
    scored by `offset_error` on the `side` x `side` patch grid, averaged over the slots, as
    `slot_angle_sum` asks the slots for the angle; weighted by each example's loss tokens."""
    error = offset_error(unit_slots(image_embeds), jnp.nan_to_num(grasp[:, :2]) / image_side, side).mean(axis=1)
    return jnp.sum(error * finite_example_tokens(loss_mask, grasp[:, :2]))


def means(sums: dict[str, jax.Array]) -> dict[str, jax.Array]:
    """Loss and accuracy per counted token (0 for a batch without any); so every auxiliary loss summed
    (a key NAME_sum other than loss_sum, its mean as NAME)."""
    count = jnp.maximum(sums["tokens"], 1).astype(jnp.float32)
    out = {"loss": sums["loss_sum"] / count, "accuracy": sums["correct"] / count}
    for key, total in sums.items():
        if key.endswith("_sum") and key != "loss_sum":
            out[key.removesuffix("_sum")] = total / count
    return out
