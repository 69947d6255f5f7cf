"""Reading a coordinate value token (x_12, y_3, w_40, ...) as the local mean of the model's distribution.

Greedy decoding answers the mode of the next token's distribution. Over coordinate value tokens that
distribution is a blurred bump a few pixels to tens of pixels wide, and its mode moves with the
blur's noise; `LocalMean(token_texts, window)` instead answers the probability-weighted mean value of
the tokens of the mode's family within `window` values of the mode (among the tokens the constraint
allows), rounded to the nearest value, and keeps the mode when that value's token is not allowed.
Angle tokens (a_k) are left to the mode. A vocabulary without value tokens (numbers="digits") leaves
every pick greedy.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.models.value_embeddings import value_tokens


def configured_value_window(config) -> int:
    """The value window a run's config sets (`decode.value_window`); 0 (greedy) for configs made before it."""
    return int(config.get("decode", {}).get("value_window", 0))


def value_picker(token_texts, window: int) -> LocalMean | None:
    """The picker a decoder takes for `window` (models.decode.generate): None (greedy) for 0."""
    return LocalMean(token_texts, window) if window else None


def greedy(logits: jax.Array, allowed: jax.Array) -> jax.Array:
    """[B, V] logits and allowed mask -> [B] int32 the most likely allowed token."""
    return jnp.argmax(jnp.where(allowed, logits, -jnp.inf), axis=-1).astype(jnp.int32)


class LocalMean:
    """`pick(logits, allowed) -> [B] tokens`: see the module docstring. Built once per vocabulary and
    window; a static argument of the jitted decoders (hashed by identity)."""

    def __init__(self, token_texts, window: int):
        if window < 0:
            raise ValueError(f"the value window must be >= 0 values, got {window}")
        self.window, self.vocab_size = int(window), len(token_texts)
        coordinates = {family: rows for family, rows in value_tokens(token_texts).items() if family != "a"}
        self.value = np.zeros(self.vocab_size, np.float32)
        self.family = np.full(self.vocab_size, -1, np.int32)
        every_value = np.concatenate([values for _, values in coordinates.values()] or [np.zeros(1, int)])
        self.offset = int(every_value.min())
        self.token_of = np.full((max(len(coordinates), 1), int(every_value.max()) - self.offset + 1), -1, np.int32)
        for index, (ids, values) in enumerate(coordinates.values()):
            self.value[ids], self.family[ids] = values, index
            self.token_of[index, values - self.offset] = ids

    def pick(self, logits: jax.Array, allowed: jax.Array) -> jax.Array:
        token = greedy(logits, allowed)
        if not self.window or logits.shape[-1] < self.vocab_size or not (self.family >= 0).any():
            return token
        extra = logits.shape[-1] - self.vocab_size  # the model's vocabulary may be padded beyond the tokenizer's
        value = jnp.asarray(np.pad(self.value, (0, extra)))
        family = jnp.asarray(np.pad(self.family, (0, extra), constant_values=-1))
        mode_family, mode_value = family[token], value[token]
        near = (family[None] == mode_family[:, None]) & (jnp.abs(value[None] - mode_value[:, None]) <= self.window) & allowed
        weights = jax.nn.softmax(jnp.where(near, logits, -jnp.inf), axis=-1)
        mean = jnp.sum(jnp.where(near, weights * value[None], 0.0), axis=-1)
        column = jnp.clip(jnp.round(mean).astype(jnp.int32) - self.offset, 0, self.token_of.shape[1] - 1)
        local = jnp.asarray(self.token_of)[jnp.maximum(mode_family, 0), column]
        usable = (mode_family >= 0) & (local >= 0) & jnp.take_along_axis(allowed, jnp.maximum(local, 0)[:, None], 1)[:, 0]
        return jnp.where(usable, local, token)
