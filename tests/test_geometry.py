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


CENTRE = "Grasp center point coordinates: "
SIZE = "Grasp width and height: "
BOX = "Grasp bounding box: "
ANGLE = "Grasp rotation angle in radians: "
GOOD = {"xya": CENTRE + "x_10,y_20", "xywha": CENTRE + "x_10,y_20 " + SIZE + "w_30,h_8",
        "tlbra": BOX + "x_5,y_10,x_15,y_30", "tlbra_patch": BOX + "<patch_index_0033><patch_index_0100>"}
# Every representation's location, broken: (representation, location text, reason in the error).
BAD_LOCATIONS = [
    ("xya", "", "no centre point"),
    ("xya", CENTRE + "x_300,y_20", "outside"),
    ("xya", CENTRE + "x_224,y_20", "outside"),
    ("xya", CENTRE + "x_10,y_-1", "outside"),
    ("xya", CENTRE + "x_\u0661\u0660,y_20", "malformed centre point"),  # Arabic-Indic digits
    ("xya", CENTRE + "x_10,y_\uff12\uff10", "malformed centre point"),  # full-width digits
    ("xya", CENTRE + "x_10,y_20abc", "malformed centre point"),
    ("xya", CENTRE + "x_10,y_20.5", "malformed centre point"),
    ("xya", CENTRE + "x_10.5,y_20", "malformed centre point"),
    ("xya", CENTRE + "x_10,y_20 " + CENTRE + "x_50,y_60", "more than one centre point"),
    ("xywha", CENTRE + "x_10,y_20", "no width and height"),
    ("xywha", SIZE + "w_30,h_8", "no centre point"),
    ("xywha", CENTRE + "x_10,y_20 " + SIZE + "w_0,h_8", "out of range"),
    ("xywha", CENTRE + "x_10,y_20 " + SIZE + "w_30,h_449", "out of range"),
    ("xywha", CENTRE + "x_10,y_20 " + SIZE + "w_-3,h_8", "out of range"),
    ("xywha", CENTRE + "x_10,y_20 " + SIZE + "w_30,h_8px", "malformed width and height"),
    ("xywha", CENTRE + "x_10,y_20 " + SIZE + "w_\u0663,h_8", "malformed width and height"),
    ("xywha", CENTRE + "x_10,y_20 " + SIZE + "w_30,h_8 " + SIZE + "w_31,h_8", "more than one width and height"),
    ("xywha", CENTRE + "x_-1,y_20 " + SIZE + "w_30,h_8", "outside"),
    ("tlbra", "", "no bounding box"),
    ("tlbra", BOX + "x_15,y_10,x_5,y_30", "wrong order"),
    ("tlbra", BOX + "x_5,y_30,x_15,y_10", "wrong order"),
    ("tlbra", BOX + "x_-300,y_10,x_15,y_30", "far outside"),
    ("tlbra", BOX + "x_5,y_10,x_15,y_449", "far outside"),
    ("tlbra", BOX + "x_-20,y_10,x_-2,y_30", "outside the 224 image"),  # the box's middle is left of it
    ("tlbra", BOX + "x_5,y_10,x_15", "malformed bounding box"),
    ("tlbra", BOX + "x_5,y_10,x_15,y_30_", "malformed bounding box"),
    ("tlbra", BOX + "x_5,y_1\u0660,x_15,y_30", "malformed bounding box"),
    ("tlbra", BOX + "x_5,y_10,x_15,y_30 " + BOX + "x_5,y_10,x_15,y_31", "more than one bounding box"),
    ("tlbra_patch", "", "no patch-index box"),
    ("tlbra_patch", BOX + "<patch_index_0033><patch_index_1024>", "above 1023"),
    ("tlbra_patch", BOX + "<patch_index_0100><patch_index_0033>", "wrong order"),
    ("tlbra_patch", BOX + "<patch_index_0040><patch_index_0100>", "wrong order"),  # column 8 > column 4
    ("tlbra_patch", BOX + "<patch_index_033><patch_index_0100>", "malformed patch-index box"),
    ("tlbra_patch", BOX + "<patch_index_\u0660033><patch_index_0100>", "malformed patch-index box"),
    ("tlbra_patch", GOOD["tlbra_patch"] + " " + GOOD["tlbra_patch"], "more than one patch-index box"),
]
BAD_ANGLES = [  # (angle text, angle_code, reason)
    ("", True, "no rotation angle"),
    (ANGLE + "a_256", True, "outside"),
    (ANGLE + "a_-1", True, "outside"),
    (ANGLE + "a_1.5", True, "outside"),
    (ANGLE + "a_12.0", True, "outside"),
    (ANGLE + "a_12abc", True, "malformed rotation angle"),
    (ANGLE + "a_12.", True, "malformed rotation angle"),  # a number ends at a non-word, non-dot character
    (ANGLE + "a_1\u0662", True, "malformed rotation angle"),
    (ANGLE + "a_12 " + ANGLE + "a_90", True, "more than one rotation angle"),
    (ANGLE + "a_12 " + ANGLE + "a_12", True, "more than one rotation angle"),
    (ANGLE + "a_1.58", False, "outside"),  # > pi/2
    (ANGLE + "a_-2", False, "outside"),
    (ANGLE + "a_0.5rad", False, "malformed rotation angle"),
    (ANGLE + "a_0.5 " + ANGLE + "a_-0.5", False, "more than one rotation angle"),
]


@pytest.mark.parametrize("representation, location, reason", BAD_LOCATIONS)
def test_bad_locations_are_clear_failures(representation, location, reason):
    for angle_code, angle in ((True, ANGLE + "a_12"), (False, ANGLE + "a_0.52")):
        parsed = grasp_text.parse_grasp(f"{location} {angle}", representation, angle_code)
        assert not parsed.ok and reason in parsed.error, parsed.error
        assert np.isnan(parsed.grasp).all()


@pytest.mark.parametrize("representation", grasp_text.REPRESENTATIONS)
@pytest.mark.parametrize("angle, angle_code, reason", BAD_ANGLES)
def test_bad_angles_are_clear_failures(representation, angle, angle_code, reason):
    parsed = grasp_text.parse_grasp(f"{GOOD[representation]} {angle}", representation, angle_code)
    assert not parsed.ok and reason in parsed.error, parsed.error
    assert np.isnan(parsed.grasp).all()


@pytest.mark.parametrize("representation", grasp_text.REPRESENTATIONS)
def test_good_answers_parse_with_text_around_them(representation):
    expected = grasp_text.parse_grasp(f"{GOOD[representation]} {ANGLE}a_12", representation)
    assert expected.ok, expected.error
    for text in (f"{GOOD[representation]} {ANGLE}a_12  \n", f"{GOOD[representation]} {ANGLE}a_12</s>",
                 f"{GOOD[representation]} {ANGLE}a_12 </s>", f"Grasp the mug. {GOOD[representation]} {ANGLE}a_12",
                 f"{ANGLE}a_12 {GOOD[representation]}"):
        parsed = grasp_text.parse_grasp(text, representation)
        assert parsed.ok, (text, parsed.error)
        np.testing.assert_array_equal(parsed.grasp, expected.grasp)


def half_up(value):
    return math.floor(value + 0.5)


@pytest.mark.parametrize("representation", grasp_text.REPRESENTATIONS)
@pytest.mark.parametrize("angle_code", [True, False])
def test_every_formatted_grasp_parses_at_the_edges(representation, angle_code):
    rng = np.random.default_rng(7)
    size = 224
    edges = np.array([0.0, -0.0, -1e-12, -0.5, -3.0, 0.49999, 0.5, 222.5, 223.0, 223.4999, 223.5, 223.75,
                      223.999999, 224.0, 224.5, 230.0])
    n = 3000
    grasps = np.c_[rng.choice(edges, (n, 2)), rng.choice([0.0, 0.2, 0.5, 1.49, 1.5, 447.5, 448.6, 1000.0], (n, 2)),
                   rng.choice([-np.pi / 2, 0.0, np.pi / 2 - 1e-9, np.pi / 4, 1.0, -0.3], n)]
    grasps[n // 2:, :2] = rng.uniform(-2, 226, (n - n // 2, 2))  # and anywhere near the image
    grasps[n // 2:, 2:4] = rng.uniform(0, 500, (n - n // 2, 2))
    for grasp in grasps:
        text = grasp_text.format_grasp(grasp, representation, angle_code, size)
        parsed = grasp_text.parse_grasp(text, representation, angle_code, size)
        assert parsed.ok, (grasp.tolist(), text, parsed.error)
        inside = np.clip(grasp[:2], 0, size - 1)
        if representation in ("xya", "xywha"):  # a centre in [223.5, 224) is written x_223, not x_224
            assert parsed.grasp[:2].tolist() == [min(max(half_up(v), 0), size - 1) for v in grasp[:2]]
        if representation == "xywha":
            assert parsed.grasp[2:4].tolist() == [min(max(half_up(v), 1), 2 * size) for v in grasp[2:4]]
        if representation == "tlbra":
            box = grasp_text.bounding_box(np.r_[inside, grasp[2:]])
            if box.min() > -size and box.max() < 2 * size:  # corners not clamped: the middle is kept
                assert np.abs(parsed.grasp[:2] - inside).max() <= 0.5 + 1e-9, (grasp.tolist(), text)


def test_split_cue_separates_each_fields_cue_from_its_value():
    texts = grasp_text.format_grasp([100.0, 50.0, 30.0, 10.0, 0.2], "xywha", angle_code=False).split(" Grasp ")
    assert [grasp_text.split_cue(t if t.startswith("Grasp") else "Grasp " + t) for t in texts] == [
        ("Grasp center point coordinates:", "x_100,y_50"), ("Grasp width and height:", "w_30,h_10"),
        ("Grasp rotation angle in radians:", "a_0.20")]
    assert grasp_text.split_cue(grasp_text.format_grasp([100.0, 50.0, 30.0, 10.0, 0.0], "tlbra_patch"))[0] == (
        "Grasp bounding box:")
    with pytest.raises(ValueError, match="no 'cue: value' form"):
        grasp_text.split_cue("x_1,y_2")


def test_patch_box_of_no_width_on_a_grid_line_parses():
    grasp = np.array([49.0, 98.0, 0.0, 0.0, 0.0])  # 49 and 98 px are grid lines of the 7 px cells
    text = grasp_text.format_grasp(grasp, "tlbra_patch")
    assert "<patch_index_0455><patch_index_0455>" in text  # row 14, column 7
    assert grasp_text.parse_grasp(text, "tlbra_patch").ok


@pytest.mark.parametrize("representation", grasp_text.REPRESENTATIONS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_format_refuses_non_finite_grasps(representation, bad):
    for field in (0, 1, 4) if representation == "xya" else range(5):
        grasp = np.array([100.0, 50.0, 30.0, 10.0, 0.2])
        grasp[field] = bad
        with pytest.raises(ValueError, match=r"cannot write grasp \[.*(nan|inf).*\] as " + representation):
            grasp_text.format_grasp(grasp, representation)
    with pytest.raises(ValueError, match="not finite"):
        grasp_text.format_angle(bad)


def test_xya_writes_what_it_parses_back():
    text = "Grasp center point coordinates: x_223,y_0 Grasp rotation angle in radians: a_255"
    parsed = grasp_text.parse_grasp(text)
    assert np.isnan(parsed.grasp[2:4]).all()  # XYA says nothing of w, h: not needed to write it again
    assert grasp_text.format_grasp(parsed.grasp) == text


def test_parse_never_raises_and_rejects_unknown_representation():
    assert not grasp_text.parse_grasp(None).ok
    assert not grasp_text.parse_grasp(BOX + "x_50,y_50,x_10,y_10 " + ANGLE + "a_1", "tlbra").ok
    with pytest.raises(ValueError, match="representation"):
        grasp_text.format_grasp([1, 2, 3, 4, 0], "xyz")
