"""Position embeddings resampled from one patch grid to another (models/patch_grid.resample_positions):
what a start trained at one image_size reads at another (config.init_resample_positions)."""

import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.models.patch_grid import resample_positions


def linear_table(side: int, width: int = 6) -> np.ndarray:
    """[1 + side * side, width]: a class row of 7s, then each cell's row a linear function of its centre
    ((column + 0.5) / side, (row + 0.5) / side), different in every column of the table."""
    centres = (np.stack(np.meshgrid(np.arange(side), np.arange(side)), -1).reshape(-1, 2) + 0.5) / side
    slopes = np.arange(2 * width, dtype=np.float64).reshape(2, width) - width
    return np.concatenate([np.full((1, width), 7.0), centres @ slopes + 1.0]).astype(np.float32)


@pytest.mark.parametrize("old, new", [(4, 8), (8, 16), (8, 12)])
def test_a_finer_grid_reads_a_linear_field_at_its_own_cell_centres(old, new):
    resampled = np.asarray(resample_positions(jnp.asarray(linear_table(old)), new))
    assert resampled.shape == (1 + new * new, 6)
    np.testing.assert_array_equal(resampled[0], 7.0)
    # bilinear interpolation is exact on a linear field between the old grid's outermost centres, and
    # holds the edge value beyond them (half a new cell at most)
    inside = np.nonzero(np.abs(((np.arange(new) + 0.5) / new) - 0.5) <= 0.5 - 0.5 / old)[0]
    cells = (inside[:, None] * new + inside[None, :]).ravel()
    want = linear_table(new)[1:][cells]
    # float32 arithmetic on values up to ~12: a few units of its resolution (1.2e-7 relative)
    np.testing.assert_allclose(resampled[1:][cells], want, rtol=1e-6, atol=1e-5)


def triangle_weights(old: int, new: int) -> np.ndarray:
    """[new, old] the weights of a tent filter one old cell wide (old / new when shrinking, the antialiasing)
    at each new cell's centre in old cell units, normalised to sum to one: bilinear resampling, written out."""
    stretch = max(old / new, 1.0)
    positions = (np.arange(new) + 0.5) * old / new - 0.5
    weights = np.maximum(0.0, 1.0 - np.abs(np.arange(old)[None] - positions[:, None]) / stretch)
    return weights / weights.sum(axis=1, keepdims=True)


@pytest.mark.parametrize("old, new", [(8, 4), (8, 16), (8, 12), (16, 8)])
def test_every_cell_is_the_tent_filtered_old_grid(old, new):
    table = np.random.default_rng(old * new).normal(size=(1 + old * old, 4)).astype(np.float32)
    resampled = np.asarray(resample_positions(jnp.asarray(table), new))
    weights = triangle_weights(old, new)
    want = np.einsum("ab,bcd,ec->aed", weights, table[1:].reshape(old, old, 4).astype(np.float64), weights)
    np.testing.assert_array_equal(resampled[0], table[0])
    # float32 sums of a few terms of size ~1 to 3: several units of its resolution
    np.testing.assert_allclose(resampled[1:].reshape(new, new, 4), want, rtol=1e-5, atol=1e-5)


def test_the_same_grid_is_returned_untouched():
    table = jnp.asarray(np.random.default_rng(0).normal(size=(1 + 64, 4)).astype(np.float32))
    assert resample_positions(table, 8) is table


def test_a_table_that_is_not_a_square_grid_or_a_side_below_one_is_refused():
    with pytest.raises(ValueError, match="do not form a square grid"):
        resample_positions(jnp.zeros((1 + 10, 4)), 4)
    with pytest.raises(ValueError, match="at least 1"):
        resample_positions(jnp.zeros((1 + 16, 4)), 0)
