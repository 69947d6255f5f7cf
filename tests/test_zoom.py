"""The mosaic zoom (scoring/zoom.py) against the mosaic's own construction (instruct.mosaic): the
quadrant a centre falls in, the zoomed view of a quadrant, and answers on it mapped back."""

import numpy as np
import pytest

from kosmos_jax.instruct.mosaic import mosaic_grasps, mosaic_image
from kosmos_jax.scoring.zoom import from_zoomed, quadrant_corners, zoomed_view

TILE = 224


def test_a_centre_s_quadrant_is_the_half_it_falls_in_and_an_unparsed_one_has_none():
    centres = np.array([[0.0, 0.0], [111.99, 111.99], [112.0, 5.0], [5.0, 112.0], [223.9, 223.9], [np.nan, 3.0]])
    assert quadrant_corners(centres, TILE).tolist() == [[0, 0], [0, 0], [112, 0], [0, 112], [112, 112], [-1, -1]]


@pytest.mark.parametrize("quadrant", range(4))
def test_a_tile_s_grasp_answered_on_its_zoomed_quadrant_lands_where_the_mosaic_put_it(quadrant):
    """Zoomed 2x, a quadrant is its tile at the tile's own scale: a grasp read there, mapped back, is the
    grasp instruct.mosaic moved into the mosaic (its affine, an independent construction)."""
    tile_grasps = np.array([[40.0, 150.0, 30.0, 12.0, 0.7], [200.5, 10.25, 20.0, 10.0, -1.2]])
    in_mosaic = mosaic_grasps(tile_grasps, quadrant, TILE)
    corners = quadrant_corners(in_mosaic[:, :2], TILE)
    row, column = divmod(quadrant, 2)
    assert corners.tolist() == [[column * TILE // 2, row * TILE // 2]] * 2
    mapped = from_zoomed(tile_grasps[:, [0, 1, 4]], corners)
    np.testing.assert_allclose(mapped, in_mosaic[:, [0, 1, 4]], rtol=1e-12)
    assert np.isnan(from_zoomed(tile_grasps[:1, [0, 1, 4]], np.array([[-1, -1]]))).all()


def bright_square_tile(x0: int, y0: int, side: int) -> np.ndarray:
    tile = np.zeros((TILE, TILE, 3), np.uint8)
    tile[y0:y0 + side, x0:x0 + side] = 255
    return tile


def weighted_centre(image: np.ndarray) -> np.ndarray:
    """(x, y) of the image's brightness centroid, pixel-corner coordinates (pixel i covers [i, i + 1))."""
    weights = image[..., 0].astype(np.float64)
    ys, xs = np.mgrid[:image.shape[0], :image.shape[1]] + 0.5
    return np.array([(xs * weights).sum(), (ys * weights).sum()]) / weights.sum()


@pytest.mark.parametrize("quadrant", range(4))
def test_the_zoomed_view_shows_the_tile_where_the_coordinates_say(quadrant):
    """A bright square in one tile of a mosaic: in the zoomed view its centroid is where it was in the tile
    (within a pixel, the 2x average and the bilinear enlargement blur its edges evenly), and the other
    tiles do not show."""
    tiles = [np.zeros((TILE, TILE, 3), np.uint8) for _ in range(4)]
    tiles[quadrant] = bright_square_tile(60, 130, 24)
    mosaic = np.asarray(mosaic_image(tiles))
    centre_in_mosaic = mosaic_grasps(np.array([[72.0, 142.0, 1.0, 1.0, 0.0]]), quadrant, TILE)[0, :2]
    np.testing.assert_allclose(weighted_centre(mosaic), centre_in_mosaic, atol=0.5)
    corner = quadrant_corners(centre_in_mosaic[None], TILE)[0]
    view = zoomed_view(mosaic, corner)
    assert view.shape == (TILE, TILE, 3) and view.dtype == np.uint8
    np.testing.assert_allclose(weighted_centre(view), [72.0, 142.0], atol=1.0)
    for other in {0, 1, 2, 3} - {quadrant}:
        row, column = divmod(other, 2)
        assert not zoomed_view(mosaic, (column * TILE // 2, row * TILE // 2)).any()


def test_a_zoom_is_refused_off_a_quadrant_corner_or_on_a_view_that_is_not_a_square_of_even_side():
    mosaic = np.zeros((TILE, TILE, 3), np.uint8)
    with pytest.raises(ValueError, match=r"\(100, 0\) is not a quadrant's corner of a 224 px mosaic"):
        zoomed_view(mosaic, (100, 0))
    with pytest.raises(ValueError, match="a mosaic is square with an even side"):
        zoomed_view(np.zeros((224, 200, 3), np.uint8), (0, 0))
    with pytest.raises(ValueError, match="a mosaic is square with an even side"):
        zoomed_view(np.zeros((223, 223, 3), np.uint8), (0, 0))

