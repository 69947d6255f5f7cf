"""The baselines (GR-ConvNet, GG-CNN2) on tiny shapes: networks, targets against their rectangles,
prediction, one training step, and RGB-D views of synthetic photos that move with the RGB."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
import scipy.ndimage
import skimage.draw
from flax import nnx

from kosmos_jax import geometry
from kosmos_jax.augment.pipeline import AugmentConfig
from kosmos_jax.baselines import family as family_lib
from kosmos_jax.baselines import inputs, losses
from kosmos_jax.baselines.ggcnn2 import GGCNN2
from kosmos_jax.baselines.grconvnet import GRConvNet
from kosmos_jax.baselines.layers import MODES, GraspMaps, input_channels
from kosmos_jax.baselines.predict import gaussian_blur, predict_grasps
from kosmos_jax.baselines.targets import WIDTH_SCALE, grasp_maps
from kosmos_jax.baselines.transpose import ConvTranspose
from kosmos_jax.sources import cornell, splits
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.dataset import views as kosmos_views
from kosmos_jax.metrics import grasp_success
from kosmos_jax.models.sharding import logical_specs

SIZE = 64
# (x, y, w, h, theta): angles across the range, one near each end of [-pi/2, pi/2)
RECTANGLES = np.array([
    [30.2, 33.7, 45.0, 16.0, 0.0],
    [32.0, 30.5, 40.0, 12.0, 0.7],
    [33.3, 31.1, 50.0, 14.0, -1.2],
    [31.0, 32.0, 42.0, 18.0, 1.55],
    [30.6, 30.6, 36.0, 15.0, -1.56],
], np.float32)


def tiny(network: str, mode: str):
    channels = input_channels(mode)
    if network == "grconvnet":
        return GRConvNet(channels, channels=4, rngs=nnx.Rngs(0))
    return GGCNN2(channels, filters=(4, 4, 8, 4), rngs=nnx.Rngs(0))


@pytest.mark.parametrize("mode", sorted(MODES))
@pytest.mark.parametrize("network", ["grconvnet", "ggcnn2"])
def test_network_gives_four_maps_of_the_input_size(network, mode):
    images = jnp.zeros((2, 32, 48, MODES[mode]), jnp.float32)
    maps = tiny(network, mode)(images)
    assert [m.shape for m in maps] == [(2, 32, 48)] * 4
    with pytest.raises(ValueError, match="divisible by 4"):
        tiny(network, mode)(jnp.zeros((1, 30, 32, MODES[mode])))


def test_network_kernels_carry_logical_axes():
    specs = logical_specs(nnx.state(tiny("grconvnet", "rgbd"), nnx.Param))
    assert tuple(specs["conv1"]["kernel"]) == ("patch", "patch", "patch", None)
    assert tuple(specs["up1"]["kernel"]) == ("patch", "patch", "patch", None)
    assert tuple(specs["bn1"]["scale"]) == ("norm",)


def _transposed_reference(x, kernel, stride, padding):
    """PyTorch's ConvTranspose2d by its definition: y[s i + k - p] += x[i] K[k] on each axis."""
    batch, height, width, _ = x.shape
    size = kernel.shape[0]
    y = np.zeros((batch, stride * height, stride * width, kernel.shape[3]))
    for i, j, a, b in np.ndindex(height, width, size, size):
        o, q = stride * i + a - padding, stride * j + b - padding
        if 0 <= o < stride * height and 0 <= q < stride * width:
            y[:, o, q] += x[:, i, j] @ kernel[a, b]
    return y


@pytest.mark.parametrize("kernel, stride, padding", [(4, 2, 1), (3, 2, 1), (9, 1, 4), (5, 2, 2), (6, 3, 2)])
def test_transposed_convolution_is_pytorchs(kernel, stride, padding):
    layer = ConvTranspose(3, 2, kernel, stride, padding, kernel_init=nnx.initializers.normal(1.0), rngs=nnx.Rngs(0))
    layer.bias[...] = jnp.asarray([0.5, -1.0])
    x = np.random.default_rng(0).normal(size=(2, 4, 5, 3)).astype(np.float32)
    expected = _transposed_reference(x, np.asarray(layer.kernel[...]), stride, padding) + [0.5, -1.0]
    np.testing.assert_allclose(np.asarray(layer(jnp.asarray(x))), expected, atol=2e-5)


@pytest.mark.parametrize("rectangle", RECTANGLES, ids=lambda r: f"theta{r[4]:+.2f}")
def test_target_maps_give_back_their_rectangle(rectangle):
    maps = grasp_maps(jnp.asarray(rectangle[None, None]), jnp.ones((1, 1), bool), SIZE)
    x, y, w, h, theta = (float(v) for v in rectangle)
    row, col = int(y), int(x)  # the pixel holding the centre
    assert maps.quality[0, row, col] == 1.0
    assert float(maps.quality[0].max()) == 1.0
    angle = 0.5 * math.atan2(float(maps.sin[0, row, col]), float(maps.cos[0, row, col]))
    assert float(geometry.angle_difference(angle, theta)) < 1e-5
    assert float(maps.width[0, row, col]) * WIDTH_SCALE == pytest.approx(w, abs=1e-3)
    # the marked pixels are those whose centre lies in the compact rectangle (w / 3 along the opening,
    # the whole jaw across), as skimage's polygon fill finds them (pixel centres at index + 0.5 here)
    compact = geometry.grasps_to_corners(np.array([x, y, w / 3, h, theta])) - 0.5
    expected = np.zeros((SIZE, SIZE), bool)
    expected[skimage.draw.polygon(compact[:, 1], compact[:, 0], (SIZE, SIZE))] = True
    differ = int((np.asarray(maps.quality[0]) != expected).sum())
    assert differ <= 2, f"{differ} pixels differ from the polygon fill"
    # background: quality and width 0, angle 0 (cos 2 theta 1), as published
    assert maps.quality[0, 0, 0] == 0 and maps.width[0, 0, 0] == 0 and maps.cos[0, 0, 0] == 1


def test_target_maps_overlap_last_wins_and_width_is_clipped():
    grasps = jnp.asarray([[[32, 32, 300.0, 20, 0.3], [32, 32, 30.0, 20, -0.9], [0, 0, 0, 0, 0]]], jnp.float32)
    mask = jnp.asarray([[True, True, False]])
    maps = grasp_maps(grasps, mask, SIZE)
    assert 0.5 * math.atan2(float(maps.sin[0, 32, 32]), float(maps.cos[0, 32, 32])) == pytest.approx(-0.9, abs=1e-5)
    assert float(maps.width[0, 32, 32]) == pytest.approx(30 / WIDTH_SCALE)
    far = geometry.grasp_axes(np.float64(0.3))[0] * 40 + 32  # on the wide rectangle only
    assert float(maps.width[0, int(far[1]), int(far[0])]) == 1.0  # 300 px clipped to 150
    empty = grasp_maps(grasps, jnp.zeros_like(mask), SIZE)
    assert float(empty.quality.sum()) == 0.0


@pytest.mark.parametrize("sigma", [1.0, 2.0])
def test_gaussian_blur_is_scipys_with_nearest_edges(sigma):
    image = np.random.default_rng(0).normal(size=(2, 20, 30)).astype(np.float32)
    expected = np.stack([scipy.ndimage.gaussian_filter(i, sigma, mode="nearest", truncate=4.0) for i in image])
    np.testing.assert_allclose(np.asarray(gaussian_blur(jnp.asarray(image), sigma)), expected, atol=1e-5)


def test_prediction_recovers_each_rectangle_from_its_maps():
    grasps = jnp.asarray(RECTANGLES[:, None])
    mask = jnp.ones((len(RECTANGLES), 1), bool)
    predicted, quality = predict_grasps(grasp_maps(grasps, mask, SIZE))
    predicted = np.asarray(predicted)
    assert predicted.shape == (len(RECTANGLES), 5)
    np.testing.assert_allclose(predicted[:, :2], RECTANGLES[:, :2], atol=1.5)
    np.testing.assert_allclose(predicted[:, 2], RECTANGLES[:, 2], atol=0.5)
    np.testing.assert_allclose(predicted[:, 3], predicted[:, 2] / 2)
    # within 0.6 degrees: the blur mixes a little of the background's angle 0 into the peak's
    assert np.all(np.asarray(geometry.angle_difference(predicted[:, 4], RECTANGLES[:, 4])) < 0.01)
    assert np.all(np.asarray(quality) > 0.9)
    # and it is scored end to end by the rectangle metric (w, h borrowed from the ground truth)
    assert bool(jnp.all(grasp_success(predicted, grasps, mask)))


def test_prediction_takes_the_angle_after_smoothing_cos_and_sin():
    """A near-vertical grasp whose raw angles straddle the +-pi/2 wrap: blurring the angle map
    would average them toward 0; blurring cos 2 theta and sin 2 theta keeps the axis vertical."""
    theta = np.where(np.indices((SIZE, SIZE)).sum(0) % 2 == 0, math.pi / 2 - 0.05, -math.pi / 2 + 0.05)
    quality = np.zeros((SIZE, SIZE), np.float32)
    quality[28:36, 28:36] = 1
    maps = (quality, np.cos(2 * theta), np.sin(2 * theta), np.full((SIZE, SIZE), 0.2))
    predicted, _ = predict_grasps(GraspMaps(*(jnp.asarray(m[None], jnp.float32) for m in maps)))
    assert float(geometry.angle_difference(predicted[0, 4], math.pi / 2)) < 0.01
    assert float(predicted[0, 2]) == pytest.approx(0.2 * WIDTH_SCALE, rel=1e-4)


def test_published_losses():
    d = jnp.asarray([-3.0, -0.5, 0.0, 0.4, 2.0])
    np.testing.assert_allclose(losses.smooth_l1(d), [2.5, 0.125, 0.0, 0.08, 1.5], rtol=1e-6)
    zeros = GraspMaps(*(jnp.zeros((2, 4, 4)),) * 4)
    ones = GraspMaps(*(jnp.full((2, 4, 4), 2.0),) * 4)
    np.testing.assert_allclose(losses.per_image(ones, zeros, "mse"), [16.0, 16.0])
    np.testing.assert_allclose(losses.per_image(ones, zeros, "smooth_l1"), [6.0, 6.0])
    assert losses.NETWORK_LOSS == {"ggcnn2": "mse", "grconvnet": "smooth_l1"}


def _batch(mode, rows=4):
    rng = np.random.default_rng(1)
    images = rng.normal(size=(rows, 32, 32, MODES[mode])).astype(np.float32)
    grasps = np.zeros((rows, 2, 5), np.float32)
    grasps[:, 0] = [16, 16, 18, 8, 0.4]
    grasps[:, 1] = [10, 20, 12, 6, -1.0]
    mask = np.array([[True, True]] * (rows - 1) + [[True, False]])
    return {"image": jnp.asarray(images), "grasps": jnp.asarray(grasps), "mask": jnp.asarray(mask)}


@pytest.mark.slow  # 17 and 12 s (make test's --durations, 2026-11-28, 2 cores)
@pytest.mark.parametrize("network, mode", [("grconvnet", "rgbd"), ("ggcnn2", "depth")])
def test_one_adam_step_lowers_the_loss(network, mode):
    config = family_lib.BaselineConfig(network=network, mode=mode, channels=4)
    family = family_lib.make_family(config)
    _, params, rest = family.init(0)
    batch = _batch(mode)
    key = jax.random.key(0)
    tx = optax.adam(1e-3)
    opt_state = tx.init(params)

    @jax.jit
    def step(params, rest, opt_state):
        (loss_sum, (sums, rest)), grads = jax.value_and_grad(family.loss_sums, has_aux=True)(
            params, rest, batch, key, True)
        grads = jax.tree.map(lambda g: g / sums["count"], grads)
        updates, opt_state = tx.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), rest, opt_state, loss_sum / sums["count"], sums

    new_params, new_rest, _, before, sums = step(params, rest, opt_state)
    after = family.loss_sums(new_params, new_rest, batch, key, True)[0] / 4
    assert int(sums["count"]) == 4
    assert float(sums["loss_sum"]) == pytest.approx(sum(float(sums[m]) for m in ("quality", "cos", "sin", "width")))
    assert float(after) < float(before)
    if network == "grconvnet":  # the running statistics moved; GG-CNN2 has none
        assert not np.allclose(new_rest["bn1"]["mean"][...], rest["bn1"]["mean"][...])
    else:
        assert not jax.tree.leaves(rest)
    grasps = family.predict(new_params, new_rest, batch["image"])
    assert grasps.shape == (4, 5) and bool(jnp.all(jnp.isfinite(grasps)))
    views = inputs.ViewArrays(*(np.asarray(batch[k]) for k in inputs.BATCH_KEYS), list("abcd"), np.zeros(4, int))
    every = family_lib.predict_views(family, new_params, new_rest, views, batch_size=3)  # a padded last batch
    np.testing.assert_allclose(every, np.asarray(grasps), atol=1e-4)
    assert grasp_success(every, batch["grasps"], batch["mask"]).shape == (4,)  # scored by the metric
    # padded evaluation rows count for nothing
    padded = {**batch, "rows": jnp.asarray([0, 1, -1, -1])}
    loss_sum, (eval_sums, same_rest) = family.loss_sums(new_params, new_rest, padded, key, False)
    assert int(eval_sums["count"]) == 2 and same_rest is new_rest


# -- inputs from synthetic photos ----------------------------------------------------------------------

@pytest.fixture(scope="session")
def synthetic_photos(tmp_path_factory):
    root = tmp_path_factory.mktemp("synthetic") / "scenes"
    scenes.write_dataset(root, 6, seed=0)
    return cornell.load_photos(root)


TWO_COPIES = AugmentConfig(rotations_per_photo=2)


def test_rgbd_views_of_a_synthetic_photo(synthetic_photos):
    photos = synthetic_photos[:2]
    index = {p.id: i for i, p in enumerate(synthetic_photos)}
    views = inputs.make_views(photos, "rgbd", TWO_COPIES, seed=0, photo_index=index, batch_size=2)
    assert views.images.shape == (4, 224, 224, 4) and views.images.dtype == np.float32
    assert views.grasps.shape[1:] == (8, 5) and views.mask.shape == views.grasps.shape[:2]
    assert views.photo_id == [photos[0].id] * 2 + [photos[1].id] * 2 and list(views.copy) == [0, 1, 0, 1]
    np.testing.assert_allclose(views.images[..., :3].mean(axis=(1, 2, 3)), 0.0, atol=1e-5)  # RGB centred
    depth = views.images[..., 3]
    assert depth.min() >= -1.0 and depth.max() <= 1.0 and depth.std() > 0  # depth centred, clipped
    for mode, channels in MODES.items():  # every mode's channels, normalised the same way
        stacked = inputs.photo_channels(photos[0], mode)
        assert stacked.shape == (480, 640, channels)
        normalised = np.asarray(inputs.normalise(stacked[None], mode))
        if mode != "rgb":
            depth = stacked[..., -1]
            np.testing.assert_allclose(normalised[0, ..., -1], np.clip(depth - depth.mean(), -1, 1), atol=1e-5)


def test_depth_moves_with_the_rgb(synthetic_photos):
    """A depth map equal to the red channel stays equal to it in every augmented and cropped view."""
    photos = [dataclasses.replace(p, depth=p.rgb[..., 0].astype(np.float32)) for p in synthetic_photos[:2]]
    index = {p.id: i for i, p in enumerate(photos)}
    for config, crop_only in ((TWO_COPIES, False), (kosmos_views.HONEST_TEST_CROP, True)):
        raw = inputs.make_views(photos, "rgbd", config, seed=3, photo_index=index, crop_only=crop_only,
                                batch_size=2, normalised=False)
        np.testing.assert_allclose(raw.images[..., 3], raw.images[..., 0], atol=1e-3)
        if not crop_only:  # the two rotations of a photo differ: the check is not of two still images
            assert raw.copy.tolist()[:2] == [0, 1] and np.abs(raw.images[0] - raw.images[1]).mean() > 1


def test_rgb_views_are_kosmos_e_views(synthetic_photos):
    """Same seed, settings and photo numbering: the RGB channels are the images KOSMOS-E's build makes."""
    photos = synthetic_photos[:2]
    index = {p.id: i for i, p in enumerate(synthetic_photos)}
    ours = inputs.make_views(photos, "rgb", TWO_COPIES, seed=5, photo_index=index, batch_size=2, normalised=False)
    theirs, _ = kosmos_views.make_views(photos, {}, TWO_COPIES, 5, index, batch_size=2)
    for row, key in enumerate(zip(ours.photo_id, ours.copy)):
        view = theirs[(key[0], int(key[1]))]
        assert np.abs(ours.images[row] - view.image.astype(np.float32)).max() <= 0.5 + 1e-3
        np.testing.assert_allclose(ours.grasps[row][ours.mask[row]], view.grasps, atol=1e-4)


def test_fold_views_use_the_folds_and_leave_out_photos_without_depth(synthetic_photos):
    photos = list(synthetic_photos)
    photos[1] = dataclasses.replace(photos[1], depth=None)
    fold = inputs.fold_views(photos, "rgbd", fold=0, scheme="object", k=3, copies=1, seed=0, batch_size=4)
    train_ids, test_ids = splits.split([p.id for p in photos], 0, "object", object_ids=[p.object_id for p in photos],
                                       k=3, seed=0)
    assert fold.missing_depth == [photos[1].id]
    assert set(fold.train.photo_id) == set(train_ids) - {photos[1].id}
    assert set(fold.test.photo_id) == set(test_ids) - {photos[1].id}
    objects = {p.id: p.object_id for p in photos}
    assert not {objects[i] for i in fold.train.photo_id} & {objects[i] for i in fold.test.photo_id}
    rgb = inputs.fold_views(photos, "rgb", fold=0, scheme="object", k=3, copies=1, seed=0, batch_size=4)
    assert rgb.missing_depth == [] and photos[1].id in rgb.train.photo_id + rgb.test.photo_id
    paper = inputs.fold_views(photos, "rgb", fold=1, scheme="image", protocol="paper", k=3, copies=2, batch_size=4)
    samples = splits.split([p.id for p in photos], 1, "image", "paper", k=3, copies_per_photo=2)
    assert list(zip(paper.test.photo_id, paper.test.copy.tolist())) == [tuple(s) for s in samples.test]


@pytest.mark.parametrize("scheme", ["image", "object"])
def test_a_validation_split_holds_out_training_photos_made_as_test_views(synthetic_photos, scheme):
    photos = list(synthetic_photos)
    whole = inputs.fold_views(photos, "rgb", fold=0, scheme=scheme, k=3, copies=1, seed=0, batch_size=4)
    held = inputs.fold_views(photos, "rgb", fold=0, scheme=scheme, k=3, copies=1, seed=0, batch_size=4,
                             validation_fraction=0.25)
    assert whole.validation is None
    object_ids = [p.object_id for p in photos] if scheme == "object" else None
    train_ids, _ = splits.split([p.id for p in photos], 0, scheme, object_ids=object_ids, k=3, seed=0)
    expected = splits.validation_split(train_ids, 0.25, scheme, seed=0, object_ids=(
        [{p.id: p.object_id for p in photos}[i] for i in train_ids] if object_ids else None))
    assert expected.validation and set(held.validation.photo_id) == set(expected.validation)
    assert set(held.train.photo_id) == set(expected.train) == set(whole.train.photo_id) - set(expected.validation)
    np.testing.assert_array_equal(held.test.images, whole.test.images)  # test untouched
    assert held.validation.copy.tolist() == [0] * len(held.validation.photo_id)  # one view a photo
    index = {p.id: i for i, p in enumerate(photos)}
    as_test = inputs.make_views([p for p in photos if p.id in expected.validation], "rgb", kosmos_views.HONEST_TEST_CROP,
                                seed=1, photo_index=index, crop_only=True, batch_size=4)
    np.testing.assert_array_equal(held.validation.images, as_test.images)
    with pytest.raises(ValueError, match="the paper protocol folds augmented copies"):
        inputs.fold_views(photos, "rgb", fold=0, protocol="paper", k=3, copies=1, batch_size=4, validation_fraction=0.25)
    with pytest.raises(ValueError, match=r"expected a number in \[0, 1\)"):
        inputs.fold_views(photos, "rgb", fold=0, k=3, copies=1, batch_size=4, validation_fraction=1.0)


def test_batches_are_a_function_of_seed_and_step():
    rows = [inputs.batch_rows(10, 3, seed=7, step=s) for s in range(6)]
    assert all(len(r) == 3 for r in rows)
    assert len(set(np.concatenate(rows[:3]).tolist())) == 9  # one epoch: no row twice
    np.testing.assert_array_equal(inputs.batch_rows(10, 3, seed=7, step=4), rows[4])
    assert not np.array_equal(inputs.batch_rows(10, 3, seed=8, step=0), rows[0])
    views = inputs.ViewArrays(np.zeros((5, 4, 4, 1), np.float32), np.zeros((5, 1, 5), np.float32),
                              np.ones((5, 1), bool), list("abcde"), np.zeros(5, int))
    resumed = next(inputs.batches(views, 2, seed=1, start_step=3))
    np.testing.assert_array_equal(resumed["rows"], inputs.batch_rows(5, 2, 1, 3))
    last = list(inputs.eval_batches(views, 2))[-1]
    assert last["rows"].tolist() == [4, -1] and last["image"].shape == (2, 4, 4, 1)
