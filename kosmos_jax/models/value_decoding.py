"""Reading a coordinate value token (x_12, y_3, w_40, ...) as the local mean of the model's distribution.

Greedy decoding answers the mode of the next token's distribution. Over coordinate value tokens that
distribution is a blurred bump a few pixels to tens of pixels wide, and its mode moves with the
blur's noise; `LocalMean(token_texts, window)` instead answers the probability-weighted mean value of
the tokens of the mode's family within `window` values of the mode (among the tokens the constraint
allows), rounded to the nearest value, and keeps the mode when that value's token is not allowed.
With `angle_window` > 0 an angle token (a_k, k of 256 bins over 180 degrees) is read the same way
around the circle: the weighted mean of the bin offsets within `angle_window` bins of the mode, taken
modulo 256 (a_255 and a_0 are neighbours), so the answer can fall between the bins the model
favours; with 0 (the default) angle tokens are left to the mode. A vocabulary without value tokens
(numbers="digits") leaves every pick greedy.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax import geometry
from kosmos_jax.models.value_embeddings import value_tokens


WINDOWS = ("value_window", "angle_window")  # how a run's answers are read: config.decode's fields, kosmos_e.json's
MAX_ANGLE_WINDOW = geometry.ANGLE_BINS // 2 - 1  # half the circle: a wider window would count a bin twice


def configured_windows(config) -> dict[str, int]:
    """{value_window, angle_window} as a run's config sets them (`config.decode`); 0 (the mode) for
    each one a config made before it lacks."""
    decode = config.get("decode", {})
    return {name: int(decode.get(name, 0)) for name in WINDOWS}


def chosen_windows(configured: dict[str, int], **given: int | None) -> dict[str, int]:
    """{value_window, angle_window}: each one given (not None), else as `configured` says."""
    return {name: configured[name] if given.get(name) is None else int(given[name]) for name in WINDOWS}


def value_picker(token_texts, window: int, angle_window: int = 0) -> LocalMean | None:
    """The picker a decoder takes for `window` and `angle_window` (models.generation.generate): None
    (greedy) when both are 0."""
    return LocalMean(token_texts, window, angle_window) if window or angle_window else None


def greedy(logits: jax.Array, allowed: jax.Array) -> jax.Array:
    """[B, V] logits and allowed mask -> [B] int32 the most likely allowed token."""
    return jnp.argmax(jnp.where(allowed, logits, -jnp.inf), axis=-1).astype(jnp.int32)


class LocalMean:
    """`pick(logits, allowed) -> [B] tokens`: see the module docstring. Built once per vocabulary and
    window; a static argument of the jitted decoders (hashed by identity)."""

    def __init__(self, token_texts, window: int, angle_window: int = 0):
        if window < 0:
            raise ValueError(f"the value window must be >= 0 values, got {window}")
        if not 0 <= angle_window <= MAX_ANGLE_WINDOW:
            raise ValueError(f"the angle window must be 0 to {MAX_ANGLE_WINDOW} bins, got {angle_window}")
        self.window, self.angle_window, self.vocab_size = int(window), int(angle_window), len(token_texts)
        families = value_tokens(token_texts)
        self.angle_bin = np.full(self.vocab_size, -1, np.int32)  # each a_k token's k, -1 for other tokens
        self.angle_token = np.full(geometry.ANGLE_BINS, -1, np.int32)  # each bin's token, -1 where missing
        if "a" in families:
            ids, bins = families["a"]
            inside = (bins >= 0) & (bins < geometry.ANGLE_BINS)
            self.angle_bin[ids[inside]], self.angle_token[bins[inside]] = bins[inside], ids[inside]
        coordinates = {family: rows for family, rows in families.items() if family != "a"}
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
        if logits.shape[-1] < self.vocab_size:
            return token
        token = self._coordinate(logits, allowed, token)
        return self._angle(logits, allowed, token)

    def _angle(self, logits: jax.Array, allowed: jax.Array, token: jax.Array) -> jax.Array:
        if not self.angle_window or not (self.angle_bin >= 0).any():
            return token
        bins = jnp.asarray(np.pad(self.angle_bin, (0, logits.shape[-1] - self.vocab_size), constant_values=-1))
        mode = bins[token]
        half = geometry.ANGLE_BINS // 2
        offset = (bins[None] - mode[:, None] + half) % geometry.ANGLE_BINS - half  # signed, around the circle
        near = (bins[None] >= 0) & (jnp.abs(offset) <= self.angle_window) & allowed
        weights = jax.nn.softmax(jnp.where(near, logits, -jnp.inf), axis=-1)
        mean = jnp.sum(jnp.where(near, weights * offset, 0.0), axis=-1)
        local = jnp.asarray(self.angle_token)[(mode + jnp.round(mean).astype(jnp.int32)) % geometry.ANGLE_BINS]
        usable = (mode >= 0) & (local >= 0) & jnp.take_along_axis(allowed, jnp.maximum(local, 0)[:, None], 1)[:, 0]
        return jnp.where(usable, local, token)

    def _coordinate(self, logits: jax.Array, allowed: jax.Array, token: jax.Array) -> jax.Array:
        if not self.window or not (self.family >= 0).any():
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
