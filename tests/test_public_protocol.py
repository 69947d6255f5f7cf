"""The baselines' own protocol, `public` (kosmos_jax.baselines' docstring): GR-ConvNet's and GG-CNN's
detection on hand-made maps against skimage's peak_local_max and gaussian (the functions their code
calls), their metric against pixel sets drawn with skimage.draw.polygon and shapely areas, their
split on a list of file names against numpy's global legacy shuffle, their label-centred crops
against array slices, and what refuses `public`."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
import pytest
from shapely.geometry import Polygon
from skimage.draw import polygon
from skimage.feature import peak_local_max
from skimage.filters import gaussian

from kosmos_jax import geometry
from kosmos_jax.train.optimizer import make_optimizer
from kosmos_jax.baselines import inputs
from kosmos_jax.baselines.layers import GraspMaps
from kosmos_jax.baselines.predict import predict_grasps
from kosmos_jax.baselines.public_detect import detect_grasps
from kosmos_jax.baselines.targets import WIDTH_SCALE
from kosmos_jax.dataset.build import BuildConfig, build
from kosmos_jax.dataset.views import evaluation_views
from kosmos_jax.experiments import spec
from kosmos_jax.metrics import grasp_success, rectangle_iou
from kosmos_jax.scoring.fold_scores import metric_settings
from kosmos_jax.scoring.view_scores import view_results
from kosmos_jax.sources import cornell, splits
from kosmos_jax.sources.synthetic import scenes

SIZE = 96  # a view big enough for a 20 px border and a 41 px window, small enough to be quick
ANGLE_TOL = 1e-5  # rad: float32 atan2 and a 17-tap blur of values below 1.6
WIDTH_TOL = 1e-4  # px: float32 products of 150 and a blur of values below 1


def bump(row: float, column: float, height: float, sigma: float = 6.0) -> np.ndarray:
    """A smooth quality hill [SIZE, SIZE] with its top at pixel (row, column)."""
    rows, columns = np.mgrid[:SIZE, :SIZE]
    return height * np.exp(-((rows - row) ** 2 + (columns - column) ** 2) / (2 * sigma ** 2))


def maps_of(quality, theta, width) -> GraspMaps:
    """GraspMaps of one view from [SIZE, SIZE] (or scalar) quality, angle in radians and width / 150."""
    full = [np.broadcast_to(np.asarray(a, np.float64), (SIZE, SIZE)) for a in (quality, theta, width)]
    quality, theta, width = full
    return GraspMaps(*(jnp.asarray(a[None], jnp.float32)
                       for a in (quality, np.cos(2 * theta), np.sin(2 * theta), width)))


def skimage_peak(maps: GraspMaps) -> list[tuple[int, int]]:
    """(row, column) of their detect_grasps' peak on the same maps: [] when none."""
    quality = gaussian(np.asarray(maps.quality[0], np.float64), 2.0, preserve_range=True)
    return [tuple(p) for p in peak_local_max(quality, min_distance=20, threshold_abs=0.2, num_peaks=1)]


def public_success(grasps, truths) -> bool:
    wh_policy, backend = metric_settings("public")
    truths = np.asarray(truths, np.float32).reshape(1, -1, 5)
    return bool(grasp_success(np.asarray(grasps, np.float32).reshape(1, 5), truths, np.ones(truths.shape[:2], bool),
                              backend=backend, wh_policy=wh_policy)[0])


def pixel_iou(a, b) -> float:
    """IoU of the integer pixel centres inside two rectangles, drawn with skimage (negative ones dropped)."""
    def pixels(grasp):
        corners = np.asarray(geometry.grasps_to_corners(np.asarray(grasp, np.float64)))
        rows, columns = polygon(corners[:, 1], corners[:, 0])
        return set(zip(rows.tolist(), columns.tolist()))
    first, second = pixels(a), pixels(b)
    return len(first & second) / len(first | second)


def shapely_iou(a, b) -> float:
    first, second = (Polygon(np.asarray(geometry.grasps_to_corners(np.asarray(g, np.float64)))) for g in (a, b))
    return first.intersection(second).area / first.union(second).area


# -- detection ------------------------------------------------------------------------------------


def test_a_peak_above_0_2_gives_the_grasp_there_with_the_map_s_angle_and_opening():
    column_ramp = 0.002 * np.arange(SIZE)[None, :]  # the opening grows to the right: read at the peak
    maps = maps_of(bump(50, 40, 0.9), 0.4, column_ramp)
    grasps, found = (np.asarray(a) for a in detect_grasps(maps))
    assert skimage_peak(maps) == [(50, 40)] and found.tolist() == [True]
    opening = 0.002 * 40 * WIDTH_SCALE  # a symmetric blur keeps a linear ramp
    np.testing.assert_allclose(grasps[0, :4], [40.5, 50.5, opening, opening / 2], atol=WIDTH_TOL)
    assert grasps[0, 4] == pytest.approx(0.4, abs=ANGLE_TOL)
    truth = [40.5, 50.5, opening, opening / 2, 0.4]
    assert public_success(grasps[0], [truth])


def test_a_peak_at_or_below_0_2_gives_no_grasp_and_a_failure():
    maps = maps_of(bump(50, 40, 0.2), 0.4, 0.3)  # 0.18 after the blur
    grasps, found = (np.asarray(a) for a in detect_grasps(maps))
    assert skimage_peak(maps) == [] and found.tolist() == [False] and np.isnan(grasps).all()
    ours, _ = predict_grasps(maps)  # our argmax still answers there
    np.testing.assert_allclose(np.asarray(ours)[0, :2], [40.5, 50.5])
    assert not public_success(grasps[0], [[40.5, 50.5, 45.0, 22.5, 0.4]])
    constant = maps_of(0.9, 0.4, 0.3)  # every pixel its window's maximum: skimage finds no peak
    assert skimage_peak(constant) == [] and not bool(detect_grasps(constant)[1][0])


def test_a_peak_inside_the_20_px_border_is_excluded():
    maps = maps_of(bump(10, 20, 0.9) + bump(70, 70, 0.5), 0.0, 0.3)
    grasps, found = (np.asarray(a) for a in detect_grasps(maps))
    assert skimage_peak(maps) == [(70, 70)] and found.tolist() == [True]
    np.testing.assert_allclose(grasps[0, :2], [70.5, 70.5])
    ours, _ = predict_grasps(maps)
    np.testing.assert_allclose(np.asarray(ours)[0, :2], [20.5, 10.5])  # our argmax takes the border's
    # a border peak alone: the interior pixels near it are not maxima of their windows, so no grasp
    alone = maps_of(bump(12, 48, 0.9), 0.0, 0.3)
    assert skimage_peak(alone) == [] and not bool(detect_grasps(alone)[1][0])


def test_the_angle_is_blurred_after_atan2_as_their_code_does():
    near_vertical = math.radians(89.0)
    theta = np.where(np.arange(SIZE)[None, :] < SIZE // 2, near_vertical, -near_vertical)
    maps = maps_of(bump(48, 48, 0.9), theta, 40 / WIDTH_SCALE)
    grasps, found = (np.asarray(a) for a in detect_grasps(maps))
    assert skimage_peak(maps) == [(48, 48)] and found.tolist() == [True]
    angle_map = 0.5 * np.arctan2(np.asarray(maps.sin[0], np.float64), np.asarray(maps.cos[0], np.float64))
    theirs = gaussian(angle_map, 2.0, preserve_range=True)[48, 48]
    assert grasps[0, 4] == pytest.approx(theirs, abs=ANGLE_TOL)
    # +89 and -89 averaged with the seam column's weight on the right: about -18 degrees, nearly flat
    assert -25 < math.degrees(theirs) < -10
    ours, _ = predict_grasps(maps)  # cos 2 theta and sin 2 theta blurred first: still near vertical
    assert math.degrees(float(geometry.angle_difference(np.asarray(ours)[0, 4], near_vertical))) < 2
    truth = [48.5, 48.5, 40.0, 20.0, near_vertical]
    assert not public_success(grasps[0], [truth])
    wh_policy, backend = metric_settings("honest")
    assert bool(grasp_success(np.asarray(ours), np.asarray([[truth]], np.float32), np.ones((1, 1), bool),
                              backend=backend, wh_policy=wh_policy)[0])


def test_the_predicted_opening_decides_success():
    truth = [48.5, 48.5, 60.0, 30.0, 0.0]
    for width, passes in ((60.0, True), (15.0, False)):
        grasps, _ = detect_grasps(maps_of(bump(48, 48, 0.9), 0.0, width / WIDTH_SCALE))
        grasp = np.asarray(grasps)[0]
        np.testing.assert_allclose(grasp, [48.5, 48.5, width, width / 2, 0.0], atol=WIDTH_TOL)
        oracle = pixel_iou(grasp, truth)
        assert float(rectangle_iou(grasp, np.asarray(truth, np.float32), backend="reference")) == pytest.approx(
            oracle, abs=1e-6)
        assert (oracle > 0.25) is passes and public_success(grasp, [truth]) is passes
    assert shapely_iou(grasp, truth) == pytest.approx(15 * 7.5 / (60 * 30), rel=1e-6)
    # borrowing the ground truth's w and h, as honest does, the narrow grasp would pass
    wh_policy, backend = metric_settings("honest")
    assert bool(grasp_success(grasp[None], np.asarray([[truth]], np.float32), np.ones((1, 1), bool),
                              backend=backend, wh_policy=wh_policy)[0])


def test_view_results_under_public_count_a_missing_grasp_as_a_failure():
    views = inputs.ViewArrays(np.zeros((2, 8, 8, 1), np.float32), np.asarray(
        [[[48.5, 48.5, 60, 30, 0.0]], [[48.5, 48.5, 60, 30, 0.0]]], np.float32), np.ones((2, 1), bool),
        ["pcd0100", "pcd0101"], np.zeros(2, int))
    grasps = np.asarray([[48.5, 48.5, 60, 30, 0.0], [np.nan] * 5], np.float32)
    results, rows = view_results(grasps, views, "public")
    assert (results["wh_policy"], results["backend"]) == ("predicted", "reference")
    assert results["accuracy"] == 50.0 and results["grasps_not_found"] == 1
    assert [r["correct"] for r in rows] == [True, False] and rows[1]["grasp"] is None and len(rows[0]["grasp"]) == 5
    narrow = grasps.copy()
    narrow[0, 2:4] = [15, 7.5]
    assert view_results(narrow, views, "public")[0]["accuracy"] == 0.0
    assert view_results(narrow, views, "honest")[0]["accuracy"] == 50.0


# -- split, crops, refusals -----------------------------------------------------------------------


def test_the_public_split_cuts_the_sorted_file_list_at_nine_tenths():
    names = [f"pcd{n:04d}" for n in range(100, 135)]  # 35 photos: 31 train, 4 test
    given = names[::-1]  # the input order does not matter: their glob is sorted
    unshuffled = splits.split(given, 0, "object", "public")
    assert unshuffled.train == names[:31] and unshuffled.test == names[31:]
    indices = list(range(len(names)))
    saved = np.random.get_state()
    try:  # their code, literally: the global legacy generator
        np.random.seed(123)
        np.random.shuffle(indices)
    finally:
        np.random.set_state(saved)
    shuffled = splits.split(given, 0, "image", "public")
    assert shuffled.train == sorted(names[i] for i in indices[:31])
    assert shuffled.test == sorted(names[i] for i in indices[31:])
    assert set(shuffled.test) != set(unshuffled.test)
    cornell_sized = splits.split([f"p{n:04d}" for n in range(885)], 0, "image", "public")
    assert (len(cornell_sized.train), len(cornell_sized.test)) == (796, 89)
    assert splits.split(given, 0, "image", "public", seed=7) != shuffled


def test_bad_input_is_refused_with_a_reason():
    names = [f"pcd{n:04d}" for n in range(100, 120)]
    with pytest.raises(ValueError, match="only fold 0"):
        splits.split(names, 1, "image", "public")
    with pytest.raises(ValueError, match="must be one of honest, paper, public"):
        splits.split(names, 0, "image", "open")
    with pytest.raises(ValueError, match="at least 2 photos"):
        splits.split(names[:1], 0, "image", "public")
    with pytest.raises(ValueError, match="scheme"):
        splits.split(names, 0, "photo", "public")
    with pytest.raises(ValueError, match="unknown protocol 'open'"):
        metric_settings("open")
    with pytest.raises(ValueError, match="must be one of honest, paper, public"):
        inputs.fold_views([], "rgb", fold=0, protocol="open")


def test_kosmos_e_s_build_views_and_sweeps_refuse_public_saying_why():
    with pytest.raises(ValueError, match="dataset build: protocol 'public' scores a baseline's"):
        build(BuildConfig(source="nowhere", protocol="public"), write=False)
    with pytest.raises(ValueError, match="evaluation views: protocol 'public' scores a baseline's"):
        evaluation_views([], protocol="public")
    with pytest.raises(spec.ExperimentError, match="scores a baseline's"):
        spec.parse_protocols("honest,public", task="kosmos_e")
    assert spec.parse_protocols("honest,paper", task="kosmos_e") == ["honest", "paper"]
    assert spec.parse_protocols("honest,public") == ["honest", "public"]  # a baseline's sweep takes it


@pytest.fixture(scope="module")
def twelve_photos(tmp_path_factory):
    root = tmp_path_factory.mktemp("public_protocol") / "scenes"
    scenes.write_dataset(root, 12, seed=3)
    return cornell.load_photos(root)


def test_fold_views_under_public_test_on_label_centred_crops_of_the_last_tenth(twelve_photos):
    photos = twelve_photos
    fold = inputs.fold_views(photos, "rgb", fold=0, scheme="object", protocol="public", copies=1, batch_size=4)
    ids = sorted(p.id for p in photos)
    assert sorted(set(fold.train.photo_id)) == ids[:10] and fold.test.photo_id == ids[10:]
    index = {p.id: i for i, p in enumerate(photos)}
    tested = [p for p in photos if p.id in ids[10:]]
    raw = inputs.make_views(tested, "rgb", inputs.PUBLIC_TEST_CROP, 0, index, crop_only=True, batch_size=4,
                            normalised=False)
    for row, photo in enumerate(sorted(tested, key=lambda p: p.id)):
        height, width = photo.rgb.shape[:2]
        centre = np.floor(photo.grasps[:, :2].mean(axis=0))
        left = int(np.clip(centre[0] - 112, 0, width - 224))
        top = int(np.clip(centre[1] - 112, 0, height - 224))
        np.testing.assert_array_equal(raw.images[row], photo.rgb[top:top + 224, left:left + 224].astype(np.float32))
        inside = np.all((photo.grasps[:, :2] - [left, top] >= 0) & (photo.grasps[:, :2] - [left, top] < 224), axis=1)
        np.testing.assert_allclose(raw.grasps[row][raw.mask[row]][:, :2], photo.grasps[inside, :2] - [left, top],
                                   atol=1e-4)
    with pytest.raises(ValueError, match="only fold 0"):
        inputs.fold_views(photos, "rgb", fold=1, scheme="image", protocol="public", copies=1)


def test_the_public_config_variants_train_on_the_shuffled_split():
    for variant, network in (("grconvnet_rgbd_public", "grconvnet"), ("ggcnn2_d_public", "ggcnn2")):
        config = spec.load_config(f"configs/baselines.py:{variant}")
        assert (config.data.protocol, config.data.scheme, config.data.fold) == ("public", "image", 0)
        assert config.model.network == network and config.data.source == "cornell"


@pytest.mark.parametrize("variant, network", [("grconvnet_rgbd_public_gpu", "grconvnet"),
                                              ("ggcnn2_d_public_gpu", "ggcnn2")])
def test_the_gpu_variants_train_the_public_schedule_and_choose_on_validation(variant, network):
    """The public codes' schedule (Adam at torch's constant 1e-3, epochs of 1,000 batches of 8), with a
    validation split scored every epoch and every epoch's checkpoint kept, so a step can be chosen on it."""
    epochs = 50  # both codes' --epochs default
    config = spec.load_config(f"configs/baselines.py:{variant}")
    assert (config.data.protocol, config.data.scheme, config.model.network) == ("public", "image", network)
    assert (config.train.steps, config.train.batch_size) == (epochs * 1_000, 8)
    _, schedule = make_optimizer(config.optimizer, config.train.steps)
    assert {float(schedule(step)) for step in (0, 1, config.train.steps // 2, config.train.steps - 1)} == {float(np.float32(1e-3))}
    assert config.optimizer.weight_decay == 0.0 and config.data.validation_fraction == 0.1
    assert config.train.eval_every == config.train.checkpoint_every == 1_000
    assert config.train.keep_checkpoints == epochs
    if network == "grconvnet":
        assert config.model.channels == 32  # the public code's --channel-size
