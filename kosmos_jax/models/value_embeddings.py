"""A smooth start for the embeddings of value tokens ("x_12", "a_77"), for models trained from scratch.

Randomly initialised, the embeddings of x_60 and x_61 are as unlike as those of x_60 and y_5, so
the tied LM head learns each coordinate value on its own from the few examples that use it. With
`model.value_token_code` = A > 0, every value token's row gets A times a unit-norm sin-cos code of
its value added to its random row: the codes of near values are near (a Gaussian-like kernel a few
pixels, or a few angle bins, wide), so a step towards x_61 is also a step towards x_60 and x_62.
The random part keeps x_v and y_v apart. Only a tokenizer with value tokens (numbers="values")
has such rows.
"""

from __future__ import annotations

import re

import numpy as np

from kosmos_jax import geometry

VALUE_TOKEN = re.compile(r"^([xywha])_(-?\d+)$")


def value_code(phases: np.ndarray, width: int, harmonic_width: float | None = None) -> np.ndarray:
    """[n] phases (radians) -> [n, width] unit-norm rows: sin and cos of harmonics 1..width/2 of
    each phase, weighted by a Gaussian in the harmonic (`harmonic_width` wide, width/8 unless given)
    so that the codes' dot product falls smoothly with the phase difference, over about
    sqrt(2) / harmonic_width radians."""
    if width % 2:
        raise ValueError(f"a value code needs an even width, got {width}")
    harmonic_width = width / 8 if harmonic_width is None else harmonic_width
    if harmonic_width <= 0:
        raise ValueError(f"a value code's harmonic width must be positive, got {harmonic_width}")
    harmonics = np.arange(1, width // 2 + 1)
    weights = np.exp(-0.5 * (harmonics / harmonic_width) ** 2)
    angles = np.asarray(phases, np.float64)[:, None] * harmonics
    code = np.concatenate([np.sin(angles) * weights, np.cos(angles) * weights], axis=1)
    return code / np.linalg.norm(code, axis=1, keepdims=True)


def value_phases(family: str, values: np.ndarray) -> np.ndarray:
    """Angle codes wrap (a_0 lies next to a_255); other values do not: the family's range in the
    vocabulary (x_0..x_223, or tlbra's -224..448) spans half a turn."""
    if family == "a":
        return 2 * np.pi * values / geometry.ANGLE_BINS
    return np.pi * (values - values.min()) / (values.max() - values.min() + 1)


def value_tokens(pieces: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{family: (ids, values)} of the value tokens among `pieces` (the tokenizer's text of each id)."""
    found: dict[str, list[tuple[int, int]]] = {}
    for token_id, piece in enumerate(pieces):
        match = VALUE_TOKEN.match(piece)
        if match:
            found.setdefault(match.group(1), []).append((token_id, int(match.group(2))))
    return {family: (np.array([i for i, _ in rows]), np.array([v for _, v in rows])) for family, rows in found.items()}


def value_rows(pieces: list[str]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{family: (ids, phases)} of the value tokens among `pieces`."""
    return {family: (ids, value_phases(family, values.astype(np.float64)))
            for family, (ids, values) in value_tokens(pieces).items()}


def angle_token_ids(pieces: list[str]) -> np.ndarray:
    """The token ids of a_0 .. a_255 in bin order among `pieces`, or an empty array when the vocabulary
    has no full set of angle value tokens."""
    rows = value_rows(pieces).get("a")
    if rows is None or len(rows[0]) != geometry.ANGLE_BINS:
        return np.zeros((0,), np.int32)
    ids, phases = rows
    return ids[np.argsort(phases)].astype(np.int32)


def angle_harmonic_width(kernel_bins: float) -> float:
    """The harmonic width whose code kernel is about `kernel_bins` angle bins wide."""
    return geometry.ANGLE_BINS * np.sqrt(2) / (2 * np.pi * kernel_bins)


def with_value_code(embedding: np.ndarray, pieces: list[str], amplitude: float, angle_kernel_bins: float = 0.0) -> np.ndarray:
    """embedding [V, D] with `amplitude` times each value token's code added to its row. With
    `angle_kernel_bins` > 0 the angle tokens' codes are that many bins alike (about; the default
    kernel, width/8 harmonics, is 2 to 3 bins at width 128): a wide kernel makes the cross-entropy's
    pull on an angle answer mostly its low harmonics, the coarse orientation."""
    if angle_kernel_bins < 0:
        raise ValueError(f"angle_kernel_bins must be >= 0, got {angle_kernel_bins}")
    rows = value_rows(pieces)
    if not rows:
        raise ValueError("model.value_token_code needs value tokens in the vocabulary "
                         "(build the data with --config.data.build.numbers=values)")
    out = np.array(embedding, copy=True)
    for family, (ids, phases) in rows.items():
        harmonic_width = angle_harmonic_width(angle_kernel_bins) if family == "a" and angle_kernel_bins else None
        out[ids] += amplitude * value_code(phases, embedding.shape[1], harmonic_width).astype(out.dtype)
    return out
