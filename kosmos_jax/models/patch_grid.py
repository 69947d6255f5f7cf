"""The vision tower's square grid of patches: which patch holds a point, a patch's centre, a fixed
sin-cos code of each cell (what `connector_extensions` adds to the patch tokens), and position
embeddings resampled from one grid to another.

Centres are (x, y) in units of the view's side; patches are row-major, the class token first where
tokens are given.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np


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


def resample_positions(table: jax.Array, side: int) -> jax.Array:
    """[1 + n * n, D] position embeddings (the class token's row, then the row-major n x n grid's) ->
    [1 + side * side, D]: the class row kept, the grid's rows resized as an image whose pixels are the cells
    (half-cell aligned, as cell_centre and grid_code place them; bilinear, antialiased when shrinking), so
    that a tower trained on one grid starts on another: ViT's fine-tuning at a new resolution."""
    old = grid_side(table.shape[0] - 1)
    if side < 1:
        raise ValueError(f"a grid side must be at least 1, got {side}")
    if side == old:
        return table
    grid = table[1:].reshape(old, old, table.shape[-1])
    resized = jax.image.resize(grid.astype(jnp.float32), (side, side, table.shape[-1]), method="bilinear")
    return jnp.concatenate([table[:1], resized.reshape(side * side, -1).astype(table.dtype)])
