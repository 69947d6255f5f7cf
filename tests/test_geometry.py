"""Grasp conventions (DESIGN section 2) and the text representations."""

import math

import cv2
import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax import geometry, grasp_text


def test_corners_to_grasp_follows_the_design_formula():
    # p0 -> p1 goes right and up on screen (y decreases): a positive angle.
    corners = np.array([[10.0, 20.0], [30.0, 10.0], [32.0, 14.0], [12.0, 24.0]])
    x, y, w, h, theta = geometry.corners_to_grasps(corners)
    assert (x, y) == pytest.approx(corners.mean(axis=0))
    assert w == pytest.approx(math.hypot(20, 10)) and h == pytest.approx(math.hypot(2, 4))
    expected = (math.atan2(-(10 - 20), 30 - 10) + math.pi / 2) % math.pi - math.pi / 2
    assert theta == pytest.approx(expected) and theta > 0


def test_round_trip_and_half_turn_symmetry():
    rng = np.random.default_rng(0)
    grasps = np.c_[rng.uniform(0, 200, (500, 2)), rng.uniform(1, 50, (500, 2)), rng.uniform(-np.pi / 2, np.pi / 2, 500)]
    np.testing.assert_allclose(geometry.corners_to_grasps(geometry.grasps_to_corners(grasps)), grasps, atol=1e-9)
    turned = grasps.copy()
    turned[:, 4] += math.pi
    np.testing.assert_allclose(geometry.grasps_to_corners(turned)[:, [2, 3, 0, 1]], geometry.grasps_to_corners(grasps), atol=1e-9)
    assert np.all(geometry.normalize_angle(turned[:, 4]) < math.pi / 2)


def test_angle_code():
    assert geometry.encode_angle(np.float64(-math.pi / 2)) == 0
    assert geometry.encode_angle(np.float64(0.0)) == 128
    assert geometry.encode_angle(np.float64(math.pi / 2 - 1e-9)) == 255  # 256 clipped
    codes = np.arange(256)
    assert np.array_equal(geometry.encode_angle(geometry.decode_angle(codes)), codes)
    theta = np.linspace(-math.pi / 2, math.pi / 2 - 1e-6, 1000)
    error = geometry.angle_difference(geometry.decode_angle(geometry.encode_angle(theta)), theta)
    # half a bin everywhere except the top half-bin, which the code clips to 255 instead of wrapping
    top = theta >= math.pi / 2 - math.pi / 512
    assert error[~top].max() <= math.pi / 512 + 1e-12
    assert error[top].max() <= math.pi / 256 + 1e-12


def test_transform_matches_opencv_and_works_in_jax():
    grasps = np.array([[120.0, 80.0, 40.0, 12.0, 0.4], [60.0, 150.0, 20.0, 8.0, -1.2]])
    matrix = geometry.rotation_matrix(np.float64(math.radians(37.0)), np.array([100.0, 90.0]))
    np.testing.assert_allclose(matrix, cv2.getRotationMatrix2D((100.0, 90.0), 37.0, 1.0), atol=1e-12)
    moved = geometry.transform_grasps(grasps, matrix)
    corners = geometry.grasps_to_corners(grasps).reshape(-1, 1, 2)
    expected = cv2.transform(corners, matrix).reshape(2, 4, 2)
    np.testing.assert_allclose(geometry.grasps_to_corners(moved), expected, atol=1e-9)
    # rotating the image anticlockwise by 37 degrees turns the grasp axis by +37 degrees
    np.testing.assert_allclose(geometry.angle_difference(moved[:, 4], grasps[:, 4] + math.radians(37)), 0, atol=1e-9)
    shift = geometry.compose(geometry.translation_matrix(np.float64(5.0), np.float64(-3.0)), matrix)
    np.testing.assert_allclose(geometry.transform_grasps(grasps, shift)[:, :2], moved[:, :2] + [5.0, -3.0], atol=1e-9)
    in_jax = geometry.transform_grasps(jnp.asarray(grasps, jnp.float32), jnp.asarray(matrix, jnp.float32))
    np.testing.assert_allclose(np.asarray(in_jax), moved, atol=1e-3)


@pytest.mark.parametrize("representation", grasp_text.REPRESENTATIONS)
def test_text_round_trip(representation):
    rng = np.random.default_rng(1)
    for _ in range(200):
        grasp = np.array([*rng.uniform(20, 200, 2), *rng.uniform(10, 40, 2), rng.uniform(-np.pi / 2, np.pi / 2)])
        text = grasp_text.format_grasp(grasp, representation)
        parsed = grasp_text.parse_grasp(text, representation)
        assert parsed.ok, (text, parsed.error)
        assert geometry.angle_difference(parsed.grasp[4], grasp[4]) <= math.pi / 512 + 1e-9
        tolerance = 224 / 32 if representation == "tlbra_patch" else 1.0
        assert np.abs(parsed.grasp[:2] - grasp[:2]).max() <= tolerance


def test_text_matches_kosmos_e_format():
    text = grasp_text.format_grasp([100.4, 50.6, 40, 10, 0.0])
    assert text == "Grasp center point coordinates: x_100,y_51 Grasp rotation angle in radians: a_128"


@pytest.mark.parametrize(
    "text, reason",
    [
        ("", "angle"),
        ("Grasp center point coordinates: x_10,y_20", "angle"),
        ("Grasp rotation angle in radians: a_12", "centre"),
        ("Grasp center point coordinates: x_300,y_20 Grasp rotation angle in radians: a_12", "outside"),
        ("Grasp center point coordinates: x_10,y_20 Grasp rotation angle in radians: a_256", "outside"),
        ("Grasp center point coordinates: x_10,y_20 Grasp rotation angle in radians: a_1.5", "outside"),
    ],
)
def test_bad_text_is_a_clear_failure(text, reason):
    parsed = grasp_text.parse_grasp(text)
    assert not parsed.ok and reason in parsed.error and np.isnan(parsed.grasp).all()


def test_parse_never_raises_and_rejects_unknown_representation():
    assert not grasp_text.parse_grasp(None).ok
    assert not grasp_text.parse_grasp("Grasp bounding box: x_50,y_50,x_10,y_10 Grasp rotation angle in radians: a_1", "tlbra").ok
    with pytest.raises(ValueError, match="representation"):
        grasp_text.format_grasp([1, 2, 3, 4, 0], "xyz")
