"""MULTI mosaics: image halving, exact grasp mapping (checked with cv2.fillPoly), position words,
distractor uniqueness and re-draw counts."""

import cv2
import jax
import numpy as np
import pytest

from kosmos_jax import geometry
from kosmos_jax.annotators.base import MissingWordsError, ObjectWords
from kosmos_jax.instruct import distractors, mosaic
from kosmos_jax.instruct.sample import View

TILE = 224
SHIFT = 8  # fillPoly fixed-point bits


def coverage(corners, size, factor):
    """[size, size] fraction of each pixel inside the polygon, from cv2.fillPoly on a canvas
    `factor` times finer (its sub-pixel centres at (k + 0.5) / factor, pixel-corner origin)."""
    canvas = np.zeros((size * factor, size * factor), np.uint8)
    points = np.round((np.asarray(corners, np.float64) * factor - 0.5) * (1 << SHIFT)).astype(np.int32)
    cv2.fillPoly(canvas, [points], 1, lineType=cv2.LINE_8, shift=SHIFT)
    return canvas.reshape(size, factor, size, factor).mean(axis=(1, 3))


def test_downsample_is_cv2_area_resize_and_jits():
    image = np.random.default_rng(0).integers(0, 256, (448, 448, 3), dtype=np.uint8)
    expected = cv2.resize(image, (224, 224), interpolation=cv2.INTER_AREA)
    np.testing.assert_array_equal(mosaic.downsample_2x(image), expected)
    np.testing.assert_array_equal(np.asarray(jax.jit(mosaic.downsample_2x)(image)), expected)
    # a batch of images takes numpy's arithmetic, not OpenCV: the same pixels
    np.testing.assert_array_equal(mosaic.downsample_2x(np.stack([image, image[::-1]])),
                                  np.stack([expected, cv2.resize(image[::-1], (224, 224), interpolation=cv2.INTER_AREA)]))
    tiles = [image[:224, :224], image[:224, 224:], image[224:, :224], image[224:, 224:]]
    np.testing.assert_array_equal(mosaic.mosaic_image(tiles), expected)
    jitted = jax.jit(lambda *t: mosaic.mosaic_image(t))(*[jax.numpy.asarray(t) for t in tiles])
    np.testing.assert_array_equal(np.asarray(jitted), expected)


def test_tiles_land_in_their_quadrants():
    tiles = [np.full((TILE, TILE, 3), 10 * (q + 1), np.uint8) for q in range(4)]
    image = mosaic.mosaic_image(tiles)
    assert image.shape == (TILE, TILE, 3)
    half = TILE // 2
    assert image[0, 0, 0] == 10 and image[0, half, 0] == 20 and image[half, 0, 0] == 30 and image[-1, -1, 0] == 40
    assert image[half - 1, half - 1, 0] == 10 and image[half, half, 0] == 40


@pytest.mark.parametrize("quadrant", range(4))
def test_rasterised_grasp_lands_on_the_same_pixels(quadrant):
    """A tile rasterised at 8 samples per pixel and halved covers each mosaic pixel exactly as the
    mapped grasp rasterised at 16 samples per mosaic pixel: the two sample grids coincide, so any
    error in the mapping (even a quarter pixel) changes some counts."""
    rng = np.random.default_rng(quadrant)
    grasps = np.array([[60.0, 100.0, 40.0, 16.0, 0.0]] + [
        [rng.uniform(50, 174), rng.uniform(50, 174), rng.uniform(10, 60), rng.uniform(5, 30), rng.uniform(-1.5, 1.5)]
        for _ in range(4)])
    for grasp in grasps:
        tiles = [np.zeros((TILE, TILE, 1)) for _ in range(4)]
        tiles[quadrant] = coverage(geometry.grasps_to_corners(grasp), TILE, 8)[..., None]
        halved = mosaic.mosaic_image(tiles)[..., 0]  # float tiles: the exact 2 x 2 mean
        moved = mosaic.mosaic_grasps(grasp[None], quadrant, TILE)[0]
        direct = coverage(geometry.grasps_to_corners(moved), TILE, 16)
        assert halved.sum() > 0
        np.testing.assert_array_equal(direct, halved)
        np.testing.assert_allclose(moved[2:4], grasp[2:4] / 2)
        assert geometry.angle_difference(moved[4], grasp[4]) < 1e-9


def test_a_quarter_pixel_error_would_be_seen():
    grasp = np.array([100.0, 90.0, 40.0, 16.0, 0.4])
    tiles = [np.zeros((TILE, TILE, 1)) for _ in range(4)]
    tiles[3] = coverage(geometry.grasps_to_corners(grasp), TILE, 8)[..., None]
    halved = mosaic.mosaic_image(tiles)[..., 0]
    wrong = mosaic.mosaic_grasps(grasp[None], 3, TILE)[0] + np.array([0.25, 0, 0, 0, 0])
    assert not np.array_equal(coverage(geometry.grasps_to_corners(wrong), TILE, 16), halved)


def test_uint8_mosaic_of_a_grasp_mask_matches_the_direct_raster():
    grasp = np.array([80.0, 120.0, 50.0, 20.0, 0.7])
    mask = (coverage(geometry.grasps_to_corners(grasp), TILE, 8) * 255).round().astype(np.uint8)
    tiles = [np.zeros((TILE, TILE, 3), np.uint8) for _ in range(4)]
    tiles[1] = np.repeat(mask[..., None], 3, axis=-1)
    halved = mosaic.mosaic_image(tiles)[..., 0].astype(np.float64) / 255
    direct = coverage(geometry.grasps_to_corners(mosaic.mosaic_grasps(grasp[None], 1, TILE)[0]), TILE, 16)
    assert np.abs(halved - direct).max() <= 1 / 255 + 1e-12


def words(name, colour="black", shape="round", purpose="holding", strategy="Grasp it."):
    return ObjectWords(name=name, colour=colour, shape=shape, purpose=purpose, strategy=strategy)


def view(photo_id, object_words, centre=(112.0, 112.0), object_id=None):
    grasp = np.array([[centre[0], centre[1], 30.0, 10.0, 0.2]])
    return View(photo_id, np.zeros((TILE, TILE, 3), np.uint8), grasp, object_words, object_id)


def test_mosaic_sample_refers_to_the_target():
    views = [view(f"p{i}", words(f"thing {i}"), centre=(40.0 + i, 50.0)) for i in range(4)]
    sample = mosaic.mosaic_sample(views, 2, "name")
    assert sample.instruction == "Grasp the thing 2." and sample.scene == "multi" and sample.target == 2
    assert sample.photo_ids == ("p0", "p1", "p2", "p3")
    np.testing.assert_allclose(sample.grasps[0, :2], [(42.0) / 2, (50.0 + TILE) / 2])
    quadrant_words = [mosaic.mosaic_sample(views, q, "position").instruction for q in range(4)]
    assert quadrant_words == [f"Grasp the object in the {w} section of this image." for w in
                              ("top left", "top right", "bottom left", "bottom right")]
    # cell mode: the target's centroid (42, 50) in the bottom-left tile -> (21, 137) -> middle left
    assert mosaic.mosaic_sample(views, 2, "position", "cell").instruction == \
        "Grasp the object in the middle left section of this image."


def test_bad_kind_and_missing_words():
    views = [view(f"p{i}", words(f"thing {i}")) for i in range(4)]
    with pytest.raises(ValueError, match=r"'angle'.*name, colour, shape, purpose, position, strategy"):
        mosaic.mosaic_sample(views, 0, "angle")
    pool = views + [view("bare", ObjectWords(name="cup"))]
    with pytest.raises(MissingWordsError, match=r"'bare'.*'purpose'"):
        mosaic.build_mosaic(pool, 4, "purpose", np.random.default_rng(0))


def crafted_pool():
    """Target 0 is a black cup (object 7). For kind name, 1 (a red cup), 3 (the same photo) and
    4 (the same object id) clash; for kind colour, 2 (black and white), 3 and 4 clash. Exactly
    three candidates are clear for each kind."""
    return [
        view("target", words("cup", colour="black"), object_id=7),
        view("a", words("cup", colour="red")),
        view("b", words("pen", colour="black and white")),
        view("target", words("cup", colour="black"), object_id=7),
        view("c", words("box", colour="blue"), object_id=7),
        view("d", words("pen", colour="red")),
        view("e", words("box", colour="white")),
    ]


@pytest.mark.parametrize("kind, clear", [("name", {2, 5, 6}), ("colour", {1, 5, 6})])
def test_unambiguous_distractors_and_redraw_counts(kind, clear):
    pool = crafted_pool()
    n_clashing = 6 - len(clear)
    total = 0
    for seed in range(400):
        sample = mosaic.build_mosaic(pool, 0, kind, np.random.default_rng(seed))
        distractor_ids = {sample.photo_ids[i] for i in range(4) if i != sample.target}
        assert distractor_ids == {pool[i].photo_id for i in clear}
        assert sample.photo_ids[sample.target] == "target"
        assert 0 <= sample.redraws <= n_clashing
        total += sample.redraws
    # all 3 clear candidates are taken; each clashing one is drawn before the last clear one with
    # probability 3/4, so E[redraws] = 3 * 3/4 = 2.25 (400 draws: standard error about 0.04)
    assert abs(total / 400 - n_clashing * 3 / 4) < 0.15


def test_draw_records_every_rejection():
    pool = crafted_pool()
    target_words = pool[0].words

    def clash(candidate, slot):
        return distractors.words_clash(target_words, pool[candidate].words, "name") or pool[candidate].object_id == 7

    for seed in range(50):
        draw = distractors.draw_distractors(len(pool), 0, np.random.default_rng(seed), clash)
        assert set(draw.chosen) == {2, 5, 6}
        assert set(draw.rejected) <= {1, 3, 4} and draw.redraws == len(draw.rejected)
        # the rejections are exactly the clashing candidates that came before the last chosen one
        order = list(np.random.default_rng(seed).permutation(len(pool)))
        order.remove(0)
        before = order[: order.index(draw.chosen[-1])]
        assert draw.rejected == tuple(c for c in before if c in {1, 3, 4})


def test_random_mode_draws_like_the_paper():
    pool = crafted_pool()
    seen = set()
    for seed in range(200):
        sample = mosaic.build_mosaic(pool, 0, "name", np.random.default_rng(seed), unambiguous=False)
        assert sample.redraws == 0
        seen |= set(sample.photo_ids)
    assert {"a", "c"} <= seen  # clashing distractors do occur when drawn at random


def test_impossible_pool_is_a_clear_error():
    pool = [view("t", words("cup")), view("u", words("cup")), view("v", words("pen")), view("w", words("box"))]
    with pytest.raises(ValueError, match=r"only 2 of 3 candidates.*'t'.*'name'"):
        mosaic.build_mosaic(pool, 0, "name", np.random.default_rng(0))


def test_cell_position_rejects_distractors_in_the_target_cell():
    # every view's object sits at the tile centre, so in the mosaic all four are at the quadrant
    # centres (56 or 168): cells top left / top right / bottom left / bottom right, never shared
    pool = [view(f"p{i}", words(f"t{i}")) for i in range(6)]
    sample = mosaic.build_mosaic(pool, 0, "position", np.random.default_rng(1), position_mode="cell")
    assert sample.redraws == 0
    # objects at the tile corner nearest the mosaic centre all fall in the "center" cell
    near = {0: (200.0, 200.0), 1: (24.0, 200.0), 2: (200.0, 24.0), 3: (24.0, 24.0)}
    for seed in range(20):
        rng = np.random.default_rng(seed)
        quadrant = int(np.random.default_rng(seed).integers(4))
        target = view("target", words("t"), centre=near[quadrant])
        pool = [target] + [view(f"in{i}", words("x"), centre=(200.0, 200.0)) for i in range(3)] + \
               [view(f"out{i}", words("y"), centre=(112.0, 112.0)) for i in range(3)]
        sample = mosaic.build_mosaic(pool, 0, "position", rng, position_mode="cell")
        assert sample.instruction == "Grasp the object in the center section of this image."
        centres = [mosaic.mosaic_grasps(v.grasps, q, TILE)[0, :2] for q, v in
                   enumerate(pool[[p.photo_id for p in pool].index(pid)] for pid in sample.photo_ids)]
        cells = [tuple(int(c) for c in np.clip(np.floor(3 * c / TILE), 0, 2)) for c in centres]
        assert cells.count((1, 1)) == 1, (seed, sample.photo_ids, cells)


def test_real_annotated_photos_make_unambiguous_mosaics(cornell_root, kosmos_e_annotations):
    from kosmos_jax.annotators.base import colour_terms
    from kosmos_jax.annotators.kosmos_e import words_from_photo
    from kosmos_jax.sources import cornell, kosmos_e_annotations as reader

    annotations = reader.read_annotations(kosmos_e_annotations)
    photos = [annotations.attach(p) for p in cornell.load_photos(cornell_root, load_images=False)]
    blank = np.zeros((TILE, TILE, 3), np.uint8)
    pool = [View(p.id, blank, p.grasps / 3, words_from_photo(p), p.object_id) for p in photos]
    rng = np.random.default_rng(0)
    for kind in ("name", "colour", "shape", "purpose", "strategy"):
        for target in range(0, len(pool), 10):
            sample = mosaic.build_mosaic(pool, target, kind, rng)
            by_id = {v.photo_id: v for v in pool}
            target_words = pool[target].words
            for q, photo_id in enumerate(sample.photo_ids):
                if q == sample.target:
                    continue
                other = by_id[photo_id]
                assert other.object_id != pool[target].object_id
                if kind == "colour":
                    assert not colour_terms(target_words.colour) <= colour_terms(other.words.colour)
                else:
                    assert getattr(other.words, kind).lower() != getattr(target_words, kind).lower()


@pytest.mark.parametrize("kind, first, second", [
    ("name", "cup", "coffee cup"), ("name", "coffee cup", "tea cup"), ("name", "a pair of sunglasses", "sunglasses"),
    ("name", "Remote Control.", "remote control"), ("shape", "round", "round and flat"),
    ("shape", "cylindrical", "Grasp the cylindrical object."), ("purpose", "writing", "writing and drawing"),
    ("purpose", "drinking coffee", "drinking coffee with milk"), ("strategy", "It is long.", "It is long and thin."),
])
def test_phrases_that_overlap_clash_both_ways(kind, first, second):
    a, b = ObjectWords(**{kind: first}), ObjectWords(**{kind: second})
    assert distractors.words_clash(a, b, kind) and distractors.words_clash(b, a, kind)


@pytest.mark.parametrize("kind, first, second", [
    ("name", "coffee cup", "coffee maker"), ("name", "cup", "spoon"), ("shape", "round and flat", "round and tall"),
    ("shape", "cylindrical", "rectangular"), ("purpose", "writing", "eating soup"),
    ("strategy", "It is long. Grasp the middle.", "It is round. Grasp the rim."),
])
def test_distinct_phrases_do_not_clash(kind, first, second):
    a, b = ObjectWords(**{kind: first}), ObjectWords(**{kind: second})
    assert not distractors.words_clash(a, b, kind) and not distractors.words_clash(b, a, kind)


def test_head_noun_counts_only_for_names():
    assert distractors.content_words("The pair of sunglasses.") == ("pair", "sunglasses")
    assert not distractors.words_clash(ObjectWords(shape="long round"), ObjectWords(shape="short round"), "shape")
    assert distractors.words_clash(ObjectWords(name="long spoon"), ObjectWords(name="wooden spoon"), "name")


def test_mosaic_rejects_a_distractor_whose_name_contains_the_target_name():
    pool = [view("target", words("cup")), view("a", words("coffee cup")), view("b", words("tea cup")),
            view("c", words("pen")), view("d", words("box")), view("e", words("spoon"))]
    total = 0
    for seed in range(100):
        sample = mosaic.build_mosaic(pool, 0, "name", np.random.default_rng(seed))
        assert {sample.photo_ids[i] for i in range(4) if i != sample.target} == {"c", "d", "e"}
        total += sample.redraws
    assert total > 0  # the clashing cups were drawn and rejected, and counted
