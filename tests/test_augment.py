"""Augmentation: images and grasps move together; the warp matches OpenCV; drops are counted.

Oracles: OpenCV's warpAffine (pixel-index convention, converted with to_pixel_index_matrix),
skimage's polygon rasteriser for rectangles, and float64 numpy geometry for the grasps.
"""

import math

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from skimage.draw import polygon as raster_polygon

from kosmos_jax import geometry
from kosmos_jax.augment import (
    PAPER_RECIPE, AugmentConfig, augment, kept_grasps, move_grasps, pad_grasps,
    to_pixel_index_matrix, warp_images,
)

PHOTO_HW = (480, 640)


def rasterise(grasp, hw):
    """Mask of the pixels whose CENTRE lies inside the rectangle (skimage, pixel indices)."""
    corners = geometry.grasps_to_corners(np.asarray(grasp, np.float64)) - 0.5  # to pixel indices
    mask = np.zeros(hw, bool)
    rows, cols = raster_polygon(corners[:, 1], corners[:, 0], hw)
    mask[rows, cols] = True
    return mask


def smooth_image(rng, hw, channels=3):
    yy, xx = np.mgrid[0:hw[0], 0:hw[1]].astype(np.float32)
    planes = [127 + 60 * np.sin(xx / rng.uniform(4, 9) + c) + 60 * np.cos(yy / rng.uniform(5, 11) + xx / 13)
              for c in range(channels)]
    return np.stack(planes, -1).astype(np.float32)


def random_affines(rng, count, centre):
    angles = rng.uniform(0, 2 * math.pi, count)
    rot = geometry.rotation_matrix(angles, np.tile(np.asarray(centre, np.float64), (count, 1)))
    shift = geometry.translation_matrix(rng.uniform(-15, 15, count), rng.uniform(-15, 15, count))
    return geometry.compose(shift, rot)


# --- (1) images and rectangles still agree after augmentation --------------------------------

@pytest.mark.parametrize("config", [AugmentConfig(rotations_per_photo=3), PAPER_RECIPE,
                                    AugmentConfig(centre_policy="random", border="constant", rotations_per_photo=3)])
def test_rasterised_rectangle_channel_moves_with_the_grasp(config):
    rng = np.random.default_rng(1)
    grasps = np.array([[[330.0, 250.0, 60.0, 24.0, 0.4]], [[300.0, 220.0, 40.0, 30.0, -1.2]]])
    mask = np.ones((2, 1), bool)
    images = rng.uniform(0, 255, (2, *PHOTO_HW, 4)).astype(np.float32)
    for b in range(2):  # channel 3 holds the rectangle, drawn independently of our geometry
        images[b, :, :, 3] = 255.0 * rasterise(grasps[b, 0], PHOTO_HW)
    out = augment(images, grasps.astype(np.float32), mask, jax.random.key(7), config)
    size = config.output_size
    checked = 0
    for row in range(out.images.shape[0]):
        if not bool(out.mask[row, 0]):
            continue
        warped = np.asarray(out.images[row, :, :, 3]) > 127.5
        expected = rasterise(np.asarray(out.grasps[row, 0], np.float64), (size, size))
        iou = (warped & expected).sum() / (warped | expected).sum()
        assert iou > 0.9, (row, iou)
        checked += 1
    assert checked >= out.images.shape[0] // 2


def test_a_pixel_and_its_grasp_coordinate_land_on_the_same_output_pixel():
    """A bright pixel (i, j) has its centre at (j + 0.5, i + 0.5) in grasp coordinates."""
    image = np.zeros((1, 40, 50, 1), np.float32)
    i, j = 13, 21
    image[0, i, j, 0] = 1.0
    # A quarter turn about a pixel corner and an integer shift map pixel centres onto pixel centres.
    matrix = geometry.compose(geometry.translation_matrix(np.float64(3.0), np.float64(-2.0)),
                              geometry.rotation_matrix(np.float64(math.pi / 2), np.array([25.0, 20.0])))
    out = np.asarray(warp_images(image, matrix[None].astype(np.float32), (40, 50)))[0, :, :, 0]
    x, y = geometry.transform_points(np.array([[j + 0.5, i + 0.5]]), matrix)[0]
    assert out[int(math.floor(y)), int(math.floor(x))] == pytest.approx(1.0, abs=1e-5)
    assert out.sum() == pytest.approx(1.0, abs=1e-4)


# --- (2) the warp against OpenCV -------------------------------------------------------------

@pytest.mark.parametrize("border, cv_border", [("reflect", cv2.BORDER_REFLECT), ("constant", cv2.BORDER_CONSTANT)])
def test_warp_matches_cv2_warp_affine(border, cv_border):
    rng = np.random.default_rng(0)
    hw, out_hw = (48, 64), (40, 56)
    images = np.stack([smooth_image(rng, hw) for _ in range(3)])
    matrices = random_affines(rng, 3, (30.0, 22.0))
    matrices[2, :, :2] *= 1.3  # a zoom too
    ours = np.asarray(warp_images(images, matrices.astype(np.float32), out_hw, border))
    ours_u8 = np.asarray(warp_images(images.astype(np.uint8), matrices.astype(np.float32), out_hw, border))
    for b in range(3):
        index_matrix = to_pixel_index_matrix(matrices[b])
        ref = cv2.warpAffine(images[b], index_matrix, out_hw[::-1], flags=cv2.INTER_LINEAR, borderMode=cv_border)
        np.testing.assert_allclose(ours[b], ref, atol=0.05)
        ref_u8 = cv2.warpAffine(images[b].astype(np.uint8), index_matrix, out_hw[::-1],
                                flags=cv2.INTER_LINEAR, borderMode=cv_border)
        diff = np.abs(ours_u8[b].astype(np.int32) - ref_u8)
        assert diff.max() <= 1 and diff.mean() < 0.01
        # The half-pixel convention matters: the grasp-coordinate matrix used as a cv2 index
        # matrix is visibly off, so the comparison above can fail.
        naive = cv2.warpAffine(images[b], matrices[b], out_hw[::-1], flags=cv2.INTER_LINEAR, borderMode=cv_border)
        assert np.abs(ours[b] - naive).mean() > 1.0


def test_warp_matches_cv2_on_noise_with_many_matrices_per_image():
    rng = np.random.default_rng(3)
    images = rng.integers(0, 256, (2, 30, 36, 3), dtype=np.uint8)
    matrices = random_affines(rng, 6, (18.0, 15.0)).reshape(2, 3, 2, 3)
    ours = np.asarray(warp_images(images, matrices.astype(np.float32), (24, 24)))
    assert ours.shape == (2, 3, 24, 24, 3) and ours.dtype == np.uint8
    for b in range(2):
        for k in range(3):
            ref = cv2.warpAffine(images[b], to_pixel_index_matrix(matrices[b, k]), (24, 24),
                                 flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
            # cv2 quantises sample positions to 1/32 pixel, which shows on noise by a few levels.
            diff = np.abs(ours[b, k].astype(np.int32) - ref)
            assert diff.max() <= 4 and diff.mean() < 0.5


def test_integer_translation_copies_pixels_exactly():
    rng = np.random.default_rng(4)
    image = rng.integers(0, 256, (1, 20, 30, 2), dtype=np.uint8)
    matrix = geometry.translation_matrix(np.float32(-5.0), np.float32(-3.0))
    out = np.asarray(warp_images(image, matrix[None], (10, 12)))
    np.testing.assert_array_equal(out[0], image[0, 3:13, 5:17])


# --- (3) grasps that leave the crop are dropped and counted ----------------------------------

def test_far_grasps_are_dropped_and_counted_exactly():
    near = [[320.0, 240.0, 30.0, 10.0, 0.1], [330.0, 236.0, 20.0, 10.0, 0.5], [312.0, 247.0, 25.0, 8.0, -0.3]]
    far = [10.0, 10.0, 30.0, 10.0, 0.0]
    grasps, mask = pad_grasps([np.array(near + [far]), np.array(near[:2])], max_grasps=6)
    images = np.zeros((2, *PHOTO_HW, 3), np.uint8)
    config = AugmentConfig(centre_policy="image_centre", rotations_per_photo=4, translations_per_rotation=2)
    out = augment(images, grasps, mask, jax.random.key(3), config)
    dropped = np.asarray(out.dropped).reshape(2, 8)
    np.testing.assert_array_equal(dropped, [[1] * 8, [0] * 8])
    np.testing.assert_array_equal(np.asarray(out.mask).reshape(2, 8, 6)[0, 0], [1, 1, 1, 0, 0, 0])
    # an independent float64 oracle for every row: move, then keep centres inside [0, 224)
    moved = geometry.transform_grasps(np.repeat(grasps, 8, 0).astype(np.float64),
                                      np.asarray(out.matrices, np.float64))
    inside = np.all((moved[..., :2] >= 0) & (moved[..., :2] < 224), axis=-1) & np.repeat(mask, 8, 0)
    np.testing.assert_array_equal(np.asarray(out.mask), inside)
    np.testing.assert_allclose(np.asarray(out.grasps)[inside], moved[inside], atol=2e-3)
    assert np.all(np.asarray(out.grasps)[~inside] == 0)
    kept, ids = kept_grasps(out, 0)
    np.testing.assert_array_equal(ids, [0, 1, 2])
    assert kept.shape == (3, 5)


def test_move_grasps_counts_centres_leaving_the_output():
    grasps = jnp.asarray([[[5.0, 5.0, 4, 2, 0], [20.0, 5.0, 4, 2, 0], [5.0, 9.5, 4, 2, 0], [0, 0, 0, 0, 0]]])
    mask = jnp.asarray([[True, True, True, False]])
    shift = geometry.translation_matrix(jnp.asarray([2.0]), jnp.asarray([0.5]))
    moved, kept, dropped = move_grasps(grasps, mask, shift, 10)
    np.testing.assert_array_equal(kept, [[True, False, False, False]])  # 22 > 10, 10.0 is outside
    np.testing.assert_array_equal(dropped, [2])
    np.testing.assert_allclose(moved[0, 0, :2], [7.0, 5.5], atol=1e-6)


# --- (4) determinism per key and the recipes --------------------------------------------------

def test_same_key_same_output_and_photos_independent_of_batch_mates():
    rng = np.random.default_rng(5)
    images = rng.integers(0, 256, (3, 60, 80, 3), dtype=np.uint8)
    grasps, mask = pad_grasps([np.array([[40.0, 30.0, 10, 5, 0.2]])] * 3)
    config = AugmentConfig(crop_size=48, output_size=32, max_translation=5.0, rotations_per_photo=2)
    keys = jax.random.split(jax.random.key(11), 3)
    first = augment(images, grasps, mask, keys, config)
    again = augment(images, grasps, mask, keys, config)
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a, b)
    # photo 0 with a different batch-mate and the same key: the same two samples
    other = augment(images[[0, 2]], grasps[[0, 2]], mask[[0, 2]], keys[jnp.array([0, 2])], config)
    np.testing.assert_array_equal(other.images[:2], first.images[:2])
    np.testing.assert_array_equal(other.matrices[2:], first.matrices[4:])
    different = augment(images, grasps, mask, jax.random.split(jax.random.key(12), 3), config)
    assert not np.allclose(different.matrices, first.matrices)
    np.testing.assert_array_equal(first.photo_index, [0, 0, 1, 1, 2, 2])
    # raw uint32 keys work as well as typed ones
    raw = augment(images, grasps, mask, jax.random.key_data(keys), config)
    np.testing.assert_array_equal(raw.images, first.images)


def test_paper_recipe_draws_four_whole_degree_angles_each_with_four_whole_pixel_shifts():
    rng = np.random.default_rng(6)
    images = rng.integers(0, 256, (2, *PHOTO_HW, 3), dtype=np.uint8)
    grasps, mask = pad_grasps([np.array([[321.0, 233.0, 40, 20, 0.3], [300.0, 250.0, 30, 20, 1.0]])] * 2)
    out = augment(images, grasps, mask, jax.random.key(0), PAPER_RECIPE)
    assert PAPER_RECIPE.augmentations_per_photo == 16 and out.images.shape == (32, 224, 224, 3)
    matrices = np.asarray(out.matrices, np.float64).reshape(2, 4, 4, 2, 3)
    degrees = np.degrees(np.arctan2(matrices[..., 0, 1], matrices[..., 0, 0])) % 360
    np.testing.assert_allclose(degrees, np.round(degrees), atol=2e-3)
    # the four shifts of one angle share its rotation and differ by whole pixels
    np.testing.assert_allclose(matrices[..., :2, :2], matrices[:, :, :1, :2, :2].repeat(4, 2), atol=1e-6)
    offsets = matrices[..., :, 2] - matrices[:, :, :1, :, 2]
    np.testing.assert_allclose(offsets, np.round(offsets), atol=2e-3)
    assert np.abs(offsets).max() <= 80
    assert len(np.unique(np.round(degrees[0, :, 0]))) > 1


@pytest.mark.parametrize("policy", ["gt_centroid", "image_centre", "random"])
def test_crop_centre_policies(policy):
    grasps, mask = pad_grasps([np.array([[250.0, 200.0, 30, 10, 0], [270.0, 230.0, 30, 10, 0]]),
                               np.array([[500.0, 420.0, 30, 10, 0]])], max_grasps=3)
    config = AugmentConfig(centre_policy=policy, max_translation=0.0, rotations_per_photo=5)
    out = augment(np.zeros((2, *PHOTO_HW, 1), np.float32), grasps, mask, jax.random.key(1), config)
    inverse = np.linalg.inv(np.concatenate([np.asarray(out.matrices, np.float64),
                                            np.tile([[[0, 0, 1.0]]], (10, 1, 1))], 1))
    # the output point (112.5, 112.5) is the first crop's centre, whatever the angle
    centre = (inverse @ np.array([112.5, 112.5, 1.0]))[:, :2].reshape(2, 5, 2)
    assert np.ptp(centre, axis=1).max() < 1e-2
    corner = centre[:, 0] - 175.5
    np.testing.assert_allclose(corner, np.round(corner), atol=1e-2)  # on the pixel grid
    assert np.all(corner >= -1e-2) and np.all(corner <= np.array([640 - 351, 480 - 351]) + 1e-2)
    if policy == "gt_centroid":
        np.testing.assert_allclose(centre[0, 0], [260.0, 215.0], atol=0.51)
        np.testing.assert_allclose(centre[1, 0], [640 - 175.5, 480 - 175.5], atol=1e-2)  # pushed inside
    elif policy == "image_centre":
        np.testing.assert_allclose(centre[:, 0], [[320.0, 240.0]] * 2, atol=0.51)


def test_gt_centroid_without_grasps_falls_back_to_the_image_centre():
    grasps, mask = pad_grasps([np.zeros((0, 5))], max_grasps=2)
    grasps[:] = np.nan  # padding rows are ignored whatever they hold
    config = AugmentConfig(max_translation=0.0)
    out = augment(np.zeros((1, *PHOTO_HW, 1), np.float32), grasps, mask, jax.random.key(2), config)
    inverse = np.linalg.inv(np.vstack([np.asarray(out.matrices[0], np.float64), [0, 0, 1.0]]))
    np.testing.assert_allclose((inverse @ [112.5, 112.5, 1.0])[:2], [320.0, 240.0], atol=0.51)
    assert int(out.dropped[0]) == 0 and not np.asarray(out.mask).any()


# --- (5) bad input ---------------------------------------------------------------------------

def test_bad_inputs_raise_clear_errors():
    images = np.zeros((2, 40, 50, 3), np.uint8)
    grasps, mask = pad_grasps([np.zeros((1, 5))] * 2)
    config = AugmentConfig(crop_size=32, output_size=16)
    key = jax.random.key(0)
    with pytest.raises(ValueError, match=r"images must be \[B, H, W, C\], got shape \(40, 50, 3\)"):
        augment(images[0], grasps, mask, key, config)
    with pytest.raises(ValueError, match=r"grasps must be \[B=2, N, 5\], got shape \(2, 1, 4\)"):
        augment(images, grasps[..., :4], mask, key, config)
    with pytest.raises(ValueError, match=r"mask must be \[B, N\]"):
        augment(images, grasps, mask[:, None], key, config)
    with pytest.raises(ValueError, match="mask must be bool, got dtype int32"):
        augment(images, grasps, mask.astype(np.int32), key, config)
    with pytest.raises(ValueError, match=r"keys must be one PRNG key or one per photo \(2\)"):
        augment(images, grasps, mask, jax.random.split(key, 3), config)
    with pytest.raises(ValueError, match="images must be uint8 or floating point, got dtype int32"):
        augment(images.astype(np.int32), grasps, mask, key, config)
    with pytest.raises(ValueError, match="centre_policy must be one of .* got 'middle'"):
        AugmentConfig(centre_policy="middle")
    with pytest.raises(ValueError, match="border must be one of .* got 'wrap'"):
        AugmentConfig(border="wrap")
    with pytest.raises(ValueError, match=r"output_size \(400\) must not exceed crop_size \(351\)"):
        AugmentConfig(output_size=400)
    with pytest.raises(ValueError, match="rotations_per_photo must be a positive integer, got 0"):
        AugmentConfig(rotations_per_photo=0)
    with pytest.raises(ValueError, match=r"matrices must be \[B, K, 2, 3\] or \[B, 2, 3\] with B = 2"):
        warp_images(images, np.zeros((3, 2, 3), np.float32), (8, 8))
    with pytest.raises(ValueError, match="grasp list 1 has 2 grasps, more than max_grasps=1"):
        pad_grasps([np.zeros((1, 5)), np.zeros((2, 5))], max_grasps=1)
    with pytest.raises(ValueError, match=r"grasp list 0 must be \[N, 5\], got shape \(3, 4\)"):
        pad_grasps([np.zeros((3, 4))])
