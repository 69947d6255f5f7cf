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


def value_code(phases: np.ndarray, width: int) -> np.ndarray:
    """[n] phases (radians) -> [n, width] unit-norm rows: sin and cos of harmonics 1..width/2 of
    each phase, weighted by a Gaussian in the harmonic (width/8 wide) so that the codes' dot product
    falls smoothly with the phase difference."""
    if width % 2:
        raise ValueError(f"a value code needs an even width, got {width}")
    harmonics = np.arange(1, width // 2 + 1)
    weights = np.exp(-0.5 * (harmonics / (width / 8)) ** 2)
    angles = np.asarray(phases, np.float64)[:, None] * harmonics
    code = np.concatenate([np.sin(angles) * weights, np.cos(angles) * weights], axis=1)
    return code / np.linalg.norm(code, axis=1, keepdims=True)


def value_phase(family: str, value: int, image_size: int) -> float:
    """Angle codes wrap (a_0 lies next to a_255); pixel values do not: half a turn spans the image."""
    if family == "a":
        return 2 * np.pi * value / geometry.ANGLE_BINS
    return np.pi * value / image_size


def value_rows(pieces: list[str], image_size: int = 224) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{family: (ids, phases)} of the value tokens among `pieces` (the tokenizer's text of each id)."""
    found: dict[str, list[tuple[int, float]]] = {}
    for token_id, piece in enumerate(pieces):
        match = VALUE_TOKEN.match(piece)
        if match:
            family, value = match.group(1), int(match.group(2))
            found.setdefault(family, []).append((token_id, value_phase(family, value, image_size)))
    return {family: (np.array([i for i, _ in rows]), np.array([p for _, p in rows])) for family, rows in found.items()}


def with_value_code(embedding: np.ndarray, pieces: list[str], amplitude: float, image_size: int = 224) -> np.ndarray:
    """embedding [V, D] with `amplitude` times each value token's code added to its row."""
    rows = value_rows(pieces, image_size)
    if not rows:
        raise ValueError("model.value_token_code needs value tokens in the vocabulary "
                         "(build the data with --config.data.build.numbers=values)")
    out = np.array(embedding, copy=True)
    for ids, phases in rows.values():
        out[ids] += amplitude * value_code(phases, embedding.shape[1]).astype(out.dtype)
    return out
