"""The rectangle metric against independent oracles: shapely for areas, skimage for pixel counts."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely
from skimage.draw import polygon as skimage_polygon

from kosmos_jax import geometry
from kosmos_jax.metrics import grasp_success, rectangle_iou


def random_pairs(rng, n, spread=15.0, low=0.0):
    def rects():
        return np.c_[rng.uniform(low, 200, (n, 2)), rng.uniform(1, 60, (n, 2)), rng.uniform(-np.pi / 2, np.pi / 2, n)]

    a, b = rects(), rects()
    b[:, :2] = a[:, :2] + rng.normal(0, spread, (n, 2))  # most pairs overlap, some do not
    return a, b


def shapely_iou(a, b):
    pa = shapely.polygons(geometry.grasps_to_corners(np.asarray(a, np.float64)))
    pb = shapely.polygons(geometry.grasps_to_corners(np.asarray(b, np.float64)))
    inter = shapely.area(shapely.intersection(pa, pb))
    union = shapely.area(pa) + shapely.area(pb) - inter
    return np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0)


def edge_cases():
    base = [50.0, 40.0, 30.0, 10.0, 0.3]
    cases = {
        "identical": (base, base),
        "contained": (base, [50.0, 40.0, 10.0, 4.0, 0.3]),
        "contained_other_angle": (base, [52.0, 41.0, 6.0, 3.0, -0.9]),
        "touching_edge": ([10.0, 10.0, 10.0, 4.0, 0.0], [20.0, 10.0, 10.0, 4.0, 0.0]),
        "touching_corner": ([10.0, 10.0, 10.0, 4.0, 0.0], [20.0, 14.0, 10.0, 4.0, 0.0]),
        "shared_edge_inside": ([10.0, 10.0, 10.0, 4.0, 0.0], [12.0, 10.0, 6.0, 4.0, 0.0]),
        "disjoint": ([10.0, 10.0, 10.0, 4.0, 0.0], [100.0, 100.0, 10.0, 4.0, 0.0]),
        "cross_90": ([50.0, 50.0, 40.0, 8.0, 0.0], [50.0, 50.0, 40.0, 8.0, math.pi / 2]),
        "cross_90_rotated": ([50.0, 50.0, 40.0, 8.0, 0.7], [50.0, 50.0, 40.0, 8.0, 0.7 - math.pi / 2]),
        "half_turn_same": (base, [50.0, 40.0, 30.0, 10.0, 0.3 - math.pi]),
        "zero_width": ([10.0, 10.0, 0.0, 4.0, 0.0], [10.0, 10.0, 10.0, 4.0, 0.0]),
        "both_zero": ([10.0, 10.0, 0.0, 0.0, 0.0], [10.0, 10.0, 0.0, 0.0, 0.0]),
    }
    names = list(cases)
    a = np.array([cases[k][0] for k in names])
    b = np.array([cases[k][1] for k in names])
    return names, a, b


def test_exact_iou_matches_shapely_in_float64():
    rng = np.random.default_rng(0)
    a, b = random_pairs(rng, 10_000)
    with jax.enable_x64(True):
        ours = np.asarray(rectangle_iou(a, b))
        assert ours.dtype == np.float64
    expected = shapely_iou(a, b)
    assert (expected > 0.25).mean() > 0.15 and (expected == 0).mean() > 0.05  # both regimes covered
    assert np.abs(ours - expected).max() <= 1e-9
    assert np.array_equal(ours > 0.25, expected > 0.25)


def test_exact_iou_matches_shapely_in_float32():
    rng = np.random.default_rng(1)
    a, b = random_pairs(rng, 10_000)
    ours = np.asarray(rectangle_iou(a.astype(np.float32), b.astype(np.float32)))
    assert ours.dtype == np.float32
    expected = shapely_iou(a.astype(np.float32), b.astype(np.float32))
    assert np.abs(ours - expected).max() <= 1e-5
    assert np.array_equal(ours > 0.25, expected > 0.25)


def test_exact_iou_edge_cases():
    names, a, b = edge_cases()
    expected = shapely_iou(a, b)
    with jax.enable_x64(True):
        ours = np.asarray(rectangle_iou(a, b))
    for name, got, want in zip(names, ours, expected):
        assert got == pytest.approx(want, abs=1e-12), name
    by_name = dict(zip(names, ours))
    assert by_name["identical"] == pytest.approx(1.0)
    assert by_name["half_turn_same"] == pytest.approx(1.0)
    assert by_name["contained"] == pytest.approx(40.0 / 300.0)
    assert by_name["touching_edge"] == 0.0 and by_name["disjoint"] == 0.0
    assert by_name["cross_90"] == pytest.approx(64.0 / (2 * 320 - 64))
    assert by_name["zero_width"] == 0.0 and by_name["both_zero"] == 0.0


def test_exact_iou_broadcasts_and_is_symmetric():
    rng = np.random.default_rng(2)
    a, b = random_pairs(rng, 12)
    table = np.asarray(rectangle_iou(a[:, None, :], b[None, :, :]))
    assert table.shape == (12, 12)
    for i in range(12):
        assert np.allclose(table[i], np.asarray(rectangle_iou(a[i], b)), atol=1e-6)
    assert np.allclose(np.asarray(rectangle_iou(a, b)), np.asarray(rectangle_iou(b, a)), atol=1e-5)


def skimage_pixel_iou(corners_a, corners_b):
    """The public GG-CNN / KOSMOS-E IoU, written out here independently with skimage."""
    rr1, cc1 = skimage_polygon(corners_a[:, 1], corners_a[:, 0])
    rr2, cc2 = skimage_polygon(corners_b[:, 1], corners_b[:, 0])
    if len(rr1) == 0 or len(rr2) == 0:
        return 0.0
    canvas = np.zeros((max(rr1.max(), rr2.max()) + 1, max(cc1.max(), cc2.max()) + 1))
    canvas[rr1, cc1] += 1
    canvas[rr2, cc2] += 1
    union = np.sum(canvas > 0)
    return 0.0 if union == 0 else np.sum(canvas == 2) / union


def test_reference_iou_matches_skimage_pixel_count():
    rng = np.random.default_rng(3)
    a, b = random_pairs(rng, 1_500, spread=8.0, low=-15.0)  # some cross the negative border
    a[:300], b[:300] = np.round(a[:300]), np.round(b[:300])  # integer, axis-aligned: boundary ties
    a[:300, 4] = b[:300, 4] = 0.0
    with jax.enable_x64(True):
        ours = np.asarray(rectangle_iou(a, b, backend="reference"))
    ca, cb = geometry.grasps_to_corners(a), geometry.grasps_to_corners(b)
    expected = np.array([skimage_pixel_iou(ca[i], cb[i]) for i in range(len(a))])
    np.testing.assert_allclose(ours, expected, atol=1e-12)


def oracle_corners(rect):
    """The four corners of (x, y, w, h, theta), written out here: w along (cos, -sin) on screen."""
    x, y, w, h, theta = rect
    u = np.array([math.cos(theta), -math.sin(theta)])
    v = np.array([math.sin(theta), math.cos(theta)])
    centre = np.array([x, y])
    return np.array([centre + a * w / 2 * u + b * h / 2 * v for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def oracle_pixels(rect, tolerance=1e-9, tie=1e-6):
    """(pixel ids, tie): every integer centre (r, c), r, c >= 0, inside or on the boundary of the
    rectangle by brute force over its bounding box, each tested against the four edge half-planes;
    `tie` is True when some centre lies so near an edge that rounding could decide it."""
    corners = oracle_corners(rect)
    low = np.maximum(np.floor(corners.min(axis=0)) - 1, 0)
    high = np.ceil(corners.max(axis=0)) + 1
    cols, rows = np.meshgrid(np.arange(low[0], high[0] + 1), np.arange(low[1], high[1] + 1))
    points = np.stack([cols.ravel(), rows.ravel()], axis=-1)
    edges = np.roll(corners, -1, axis=0) - corners
    offsets = points[:, None, :] - corners[None]
    cross = edges[None, :, 0] * offsets[..., 1] - edges[None, :, 1] * offsets[..., 0]
    nxt = np.roll(corners, -1, axis=0)
    orientation = np.sign(np.sum(corners[:, 0] * nxt[:, 1] - nxt[:, 0] * corners[:, 1]))  # shoelace
    distance = orientation * cross / np.linalg.norm(edges, axis=1)  # >= 0 inside, for either winding
    inside = (distance >= -tolerance).all(axis=1)
    tie = bool(((distance >= -tie).all(axis=1) & (np.abs(distance) < tie).any(axis=1)).any())
    ids = (points[inside, 1] * 100_000 + points[inside, 0]).astype(np.int64)
    return ids, tie


def oracle_iou(a, b):
    pixels_a, tie_a = oracle_pixels(a)
    pixels_b, tie_b = oracle_pixels(b)
    inter = len(np.intersect1d(pixels_a, pixels_b))
    union = len(pixels_a) + len(pixels_b) - inter
    return (inter / union if union else 0.0), tie_a or tie_b


def test_reference_iou_matches_a_brute_force_pixel_count():
    """Exact equality with an oracle written here: random rotated rectangles, many across the
    negative rows and columns. Random float corners put a pixel centre within 1e-6 of an edge in
    about 4 pairs in 10^4 (7 of 20 000 when measured, none of which differed); such a pair is a tie
    that float rounding decides, possibly differently in the two computations, so it is set aside,
    and there must be almost none."""
    rng = np.random.default_rng(11)
    a, b = random_pairs(rng, 1_200, spread=8.0, low=-25.0)
    assert ((a[:, :2] < 10).any(axis=1)).mean() > 0.1  # plenty near or across the negative border
    with jax.enable_x64(True):
        ours = np.asarray(rectangle_iou(a, b, backend="reference"))
    results = [oracle_iou(a[i], b[i]) for i in range(len(a))]
    expected = np.array([iou for iou, _ in results])
    ties = np.array([tie for _, tie in results])
    assert ties.sum() <= 3
    assert (expected > 0.25).mean() > 0.15 and (expected == 0).mean() > 0.05
    mismatched = np.nonzero((ours != expected) & ~ties)[0]
    assert len(mismatched) == 0, [(a[i].tolist(), b[i].tolist(), ours[i], expected[i]) for i in mismatched[:3]]


def test_reference_iou_counts_boundary_pixels_like_the_oracle():
    """Integer axis-aligned rectangles: every corner and every half-plane test is exact, so pixel
    centres ON an edge are compared too (both count them)."""
    rng = np.random.default_rng(12)
    n = 400
    a = np.c_[rng.integers(-10, 60, (n, 2)), 2 * rng.integers(1, 15, (n, 2)), np.zeros(n)].astype(np.float64)
    b = a.copy()
    b[:, :2] += rng.integers(-12, 13, (n, 2))
    b[:, 2:4] = 2 * rng.integers(1, 15, (n, 2))
    with jax.enable_x64(True):
        ours = np.asarray(rectangle_iou(a, b, backend="reference"))
    expected = np.array([oracle_iou(a[i], b[i])[0] for i in range(n)])
    assert np.array_equal(ours, expected)
    # 2x2 square centred on (0, 0): only (0, 0), (0, 1), (1, 0), (1, 1) survive at r, c >= 0
    assert oracle_pixels(np.array([0.0, 0.0, 2.0, 2.0, 0.0]))[0].tolist() == [0, 1, 100_000, 100_001]


def test_reference_iou_drops_negative_pixels_and_flags_oversized():
    # Half of this square is at negative columns: only the columns 0..5 count.
    square = np.array([0.0, 10.0, 10.0, 10.0, 0.0])
    shifted = np.array([5.0, 10.0, 10.0, 10.0, 0.0])
    with jax.enable_x64(True):
        iou = float(rectangle_iou(square, shifted, backend="reference"))
        huge = float(rectangle_iou(square, np.array([50.0, 50.0, 10.0, 2000.0, 0.0]), backend="reference"))
    # square: columns 0..5 x rows 5..15 (66 px); shifted: columns 0..10 (121 px); all of square inside
    assert iou == pytest.approx(66 / 121)
    assert math.isnan(huge)


def test_unknown_backend_and_bad_shapes():
    with pytest.raises(ValueError, match="backend"):
        rectangle_iou(np.zeros(5), np.zeros(5), backend="fast")
    with pytest.raises(ValueError, match=r"\[\.\.\., 5\]"):
        rectangle_iou(np.zeros(4), np.zeros(5))


def gate_case(pred_deg, gt_deg):
    gts = np.array([[[50.0, 50.0, 30.0, 10.0, math.radians(gt_deg)]]])
    pred = np.array([[50.0, 50.0, math.radians(pred_deg)]])
    return bool(grasp_success(pred, gts, np.ones((1, 1), bool))[0])


def test_angle_gate():
    assert float(geometry.angle_difference(math.radians(89), math.radians(-89))) == pytest.approx(math.radians(2), abs=1e-9)
    assert float(geometry.angle_difference(math.radians(-89), math.radians(89))) == pytest.approx(math.radians(2), abs=1e-9)
    assert gate_case(30.0, 0.0)
    assert not gate_case(30.5, 0.0)
    assert gate_case(89.0, -89.0)  # a 2 degree difference modulo 180
    assert gate_case(-89.0, 89.0)
    assert not gate_case(45.0, -45.0)


def test_grasp_success_policies():
    gts = np.array([[[100.0, 100.0, 40.0, 10.0, 0.0], [0.0, 0.0, 60.0, 30.0, 0.0]]])
    mask = np.array([[True, True]])
    near = np.array([[112.0, 100.0, 0.0]])
    # per_gt: 40x10 shifted by 12 -> IoU 28/52 > 0.25
    assert bool(grasp_success(near, gts, mask)[0])
    # kosmos_e: w = 60 (widest), h = 20 (mean jaw): x 82..142, y 90..110 against x 80..120, y 95..105
    ok, best = grasp_success(near, gts, mask, wh_policy="kosmos_e", return_iou=True)
    assert bool(ok[0]) and float(best[0]) == pytest.approx(380 / (1200 + 400 - 380), abs=1e-5)
    # predicted w/h: a tiny rectangle fails
    tiny = np.array([[112.0, 100.0, 2.0, 2.0, 0.0]])
    assert not bool(grasp_success(tiny, gts, mask, wh_policy="predicted")[0])
    with pytest.raises(ValueError, match="predicted"):
        grasp_success(near, gts, mask, wh_policy="predicted")


def test_grasp_success_respects_mask_nan_and_backends():
    gts = np.array([[[100.0, 100.0, 40.0, 10.0, 0.0], [10.0, 10.0, 40.0, 10.0, 0.0]]] * 3)
    mask = np.array([[True, False], [False, True], [True, True]])
    pred = np.array([[100.0, 100.0, 0.0], [100.0, 100.0, 0.0], [np.nan, np.nan, np.nan]])
    for backend in ("exact", "reference"):
        assert grasp_success(pred, gts, mask, backend=backend).tolist() == [True, False, False]


def test_grasp_success_inside_jit_and_bad_input():
    gts = jnp.array([[[100.0, 100.0, 40.0, 10.0, 0.0]]])
    mask = jnp.ones((1, 1), bool)

    @jax.jit
    def evaluate(pred):
        return grasp_success(pred, gts, mask)

    assert bool(evaluate(jnp.array([[101.0, 99.0, 0.1]]))[0])
    with pytest.raises(ValueError, match="pred"):
        grasp_success(np.zeros((1, 4)), gts, mask)
    with pytest.raises(ValueError, match="gt_mask"):
        grasp_success(np.zeros((1, 3)), gts, np.ones((1, 2), bool))
    with pytest.raises(ValueError, match="wh_policy"):
        grasp_success(np.zeros((1, 3)), gts, mask, wh_policy="mean")


@pytest.mark.parametrize("backend", ["exact", "reference"])
@pytest.mark.parametrize("wh_policy", ["per_gt", "kosmos_e", "predicted"])
def test_grasp_success_without_any_ground_truth(backend, wh_policy):
    pred = np.array([[100.0, 100.0, 20.0, 10.0, 0.0], [50.0, 60.0, 20.0, 10.0, 0.3]])
    ok, best = grasp_success(pred, np.zeros((2, 0, 5)), np.zeros((2, 0), bool), backend=backend,
                             wh_policy=wh_policy, return_iou=True)
    assert np.asarray(ok).tolist() == [False, False] and np.asarray(best).tolist() == [0.0, 0.0]
    assert grasp_success(pred[:, [0, 1, 4]] if wh_policy != "predicted" else pred, np.zeros((2, 0, 5)),
                         np.zeros((2, 0), bool), backend=backend, wh_policy=wh_policy).shape == (2,)
    if wh_policy == "predicted":  # checked as with ground truths: [B, 3] has no w, h to keep
        with pytest.raises(ValueError, match="'predicted' needs predictions"):
            grasp_success(pred[:, [0, 1, 4]], np.zeros((2, 0, 5)), np.zeros((2, 0), bool), backend=backend,
                          wh_policy=wh_policy)


@pytest.mark.parametrize("backend", ["exact", "reference"])
def test_rectangle_iou_of_no_ground_truth_is_empty(backend):
    pred = jnp.array([[100.0, 100.0, 20.0, 10.0, 0.0], [50.0, 60.0, 20.0, 10.0, 0.3]])
    assert rectangle_iou(pred[:, None], jnp.zeros((2, 0, 5)), backend).shape == (2, 0)
