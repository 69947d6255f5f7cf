"""Formatter and prompt layout: parts, parse-back, loss mask span, image slots, overflow, settings."""

import math

import numpy as np
import pytest

from kosmos_jax import geometry, grasp_text
from kosmos_jax.instruct.sample import Sample
from kosmos_jax.text import layout
from kosmos_jax.text import tokens as special
from kosmos_jax.text.formatter import FormatConfig, check_part, format_sample, parse_target, prompt_cues, target_text
from kosmos_jax.text.tokenizer import train_tokenizer

SIZE = 224


def _grasps(n, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack(
        [rng.uniform(0, SIZE, n), rng.uniform(0, SIZE, n), rng.uniform(5, 80, n), rng.uniform(5, 40, n), rng.uniform(-np.pi / 2, np.pi / 2, n)],
        axis=1,
    )


def _sample(grasps, kind="name", instruction="Grasp the black remote control.", answer="grasp"):
    return Sample(
        kind=kind,
        scene="single",
        instruction=instruction,
        answer=answer,
        image=np.zeros((SIZE, SIZE, 3), np.uint8),
        grasps=grasps,
        photo_ids=("pcd0100",),
        object_ids=(3,),
    )


@pytest.fixture(scope="module")
def tokenizer():
    texts = ["Grasp the black remote control.", "Grasp the object with a rotation angle of a_12 radians."]
    for representation in grasp_text.REPRESENTATIONS:
        texts += [grasp_text.format_grasp(g, representation, code) for g in _grasps(20) for code in (True, False)]
    return train_tokenizer(texts, text_pieces=300)


def _tolerance(representation, angle_code):
    centre = SIZE / grasp_text.PATCH_GRID if representation == "tlbra_patch" else 0.5 + 1e-9
    # half a bin, except in the last half bin below pi/2, which the code clips to 255: one bin
    angle = math.pi / geometry.ANGLE_BINS + 1e-9 if angle_code else 0.005 + 1e-9
    return centre, angle


@pytest.mark.parametrize("representation", grasp_text.REPRESENTATIONS)
@pytest.mark.parametrize("angle_code", [True, False])
@pytest.mark.parametrize("individual", [True, False])
def test_targets_parse_back(representation, angle_code, individual):
    config = FormatConfig(representation=representation, angle_code=angle_code, individual=individual, target_grasp="each")
    grasps = _grasps(50, seed=1)
    grasps[:3, 4] = [np.pi / 2 - 1e-4, -np.pi / 2, np.pi / 2 - np.pi / 512]  # the ends of the angle code
    grasps[:, :2] = np.clip(grasps[:, :2], 0, SIZE - 1)  # the centre clip of the formatter, tested below
    if representation == "tlbra_patch":
        # patch indices clip the box to the image; keep the boxes inside to compare centres
        boxes = np.stack([grasp_text.bounding_box(g) for g in grasps])
        grasps = grasps[(boxes[:, :2] >= 0).all(1) & (boxes[:, 2:] <= SIZE).all(1)]
    examples = format_sample(_sample(grasps), config)
    assert len(grasps) > 10 and len(examples) == len(grasps) * (2 if individual else 1)
    centre_tol, angle_tol = _tolerance(representation, angle_code)
    for example in examples:
        parsed = parse_target(example.target_text, example.part, config)
        assert parsed.ok, (example.target_text, parsed.error)
        stated = example.grasp_mask
        if example.part == "angle":
            assert np.all(np.isnan(parsed.grasp[:4]))
        assert not np.any(np.isnan(parsed.grasp[stated]))
        if stated[0]:
            assert np.all(np.abs(parsed.grasp[:2] - example.grasp[:2]) <= centre_tol)
        if stated[2]:
            assert np.all(np.abs(parsed.grasp[2:4] - example.grasp[2:4]) <= 0.5 + 1e-9)
        if stated[4]:
            if angle_code:  # the parse gives the code's own angle back exactly
                assert parsed.grasp[4] == pytest.approx(float(geometry.decode_angle(geometry.encode_angle(example.grasp[4]))))
            assert geometry.angle_difference(parsed.grasp[4], example.grasp[4]) <= angle_tol
    parts = sorted({e.part for e in examples})
    assert parts == (["angle", "location"] if individual else ["grasp"])


def test_xya_individual_text_is_the_papers():
    grasp = np.array([100.4, 57.6, 40.0, 20.0, 0.3])
    centre, angle = format_sample(_sample(grasp[None]), FormatConfig())
    assert (centre.cue, centre.value) == ("Grasp center point coordinates:", "x_100,y_58")
    assert (angle.cue, angle.value) == ("Grasp rotation angle in radians:", f"a_{int(geometry.encode_angle(0.3))}")
    assert centre.target_text + " " + angle.target_text == grasp_text.format_grasp(grasp)
    assert prompt_cues(FormatConfig()) == [("location", centre.cue), ("angle", angle.cue)]
    assert prompt_cues(FormatConfig(individual=False)) == [("grasp", "")]


def test_angle_instruction_answers_location_only():
    sample = _sample(_grasps(3), kind="angle", instruction="Grasp the object with a rotation angle of a_12 radians.", answer="centre")
    for individual in (True, False):
        examples = format_sample(sample, FormatConfig(individual=individual))
        assert [e.part for e in examples] == ["location"]
        assert examples[0].grasp_mask.tolist() == [True, True, False, False, False]


def test_target_grasp_choice():
    grasps = _grasps(5)
    first = format_sample(_sample(grasps), FormatConfig(target_grasp="first", individual=False))
    assert len(first) == 1 and np.array_equal(first[0].grasp, grasps[0])
    drawn = format_sample(_sample(grasps), FormatConfig(target_grasp="random", individual=False), np.random.default_rng(4))
    assert any(np.array_equal(drawn[0].grasp, g) for g in grasps)
    assert np.array_equal(drawn[0].answers, grasps)
    with pytest.raises(ValueError, match="Generator"):
        format_sample(_sample(grasps), FormatConfig(target_grasp="random"))


def _rows(centres, angles):
    return np.array([[x, y, 30.0, 10.0, a] for (x, y), a in zip(centres, angles)])


@pytest.mark.parametrize("order", [0, 1, 2])
def test_top_target_is_a_function_of_the_grasps_whatever_their_order(order):
    """A ring's rim grasps answer with the top one, a lying bar's with its middle, a standing bar's with its
    upper end (image y grows downwards), whichever row each is in."""
    ring = [(100 + 30 * np.cos(t), 120 + 30 * np.sin(t)) for t in np.linspace(0, 2 * np.pi, 12, endpoint=False)]
    lying, standing = [(60 + 20 * i, 100) for i in range(7)], [(100, 50 + 20 * i) for i in range(5)]
    # every grasp its own angle, so that the angle example shows which grasp it came from
    cases = [(centres, np.linspace(-1.5, 1.5, len(centres)), expected)
             for centres, expected in ((ring, (100.0, 90.0)), (lying, (120.0, 100.0)), (standing, (100.0, 50.0)))]
    for centres, angles, expected in cases:
        grasps = np.random.default_rng(order).permutation(_rows(centres, angles))
        (location, angle) = format_sample(_sample(grasps), FormatConfig(target_grasp="top"))
        np.testing.assert_allclose(location.grasp[:2], expected, atol=1e-9)
        assert location.grasp.tolist() == angle.grasp.tolist()  # the angle asked apart is the same grasp's
        assert np.array_equal(location.answers, grasps)  # every grasp still answers when scored


def test_top_target_of_one_grasp_and_of_a_tie():
    (only,) = format_sample(_sample(_rows([(5, 7)], [0.3])), FormatConfig(target_grasp="top", individual=False))
    assert only.grasp[:2].tolist() == [5.0, 7.0]
    tie = _rows([(10, 50), (30, 50)], [0.0, 1.0])  # two grasps side by side: both as near; the first row
    (first,) = format_sample(_sample(tie), FormatConfig(target_grasp="top", individual=False))
    assert first.grasp[4] == 0.0
    with pytest.raises(ValueError, match="target_grasp"):
        FormatConfig(target_grasp="nearest")


def shapely_hit_counts(grasps):
    """How many of `grasps` each one hits as a prediction (its x, y, theta with the other's w, h): IoU by
    shapely, angle within 30 degrees modulo pi; the independent oracle of consensus_row."""
    shapely = pytest.importorskip("shapely")
    polygon = lambda g: shapely.Polygon(geometry.grasps_to_corners(np.asarray(g, np.float64)))  # noqa: E731
    counts = []
    for x, y, _, _, theta in grasps:
        hits = 0
        for other in grasps:
            mine, theirs = polygon([x, y, other[2], other[3], theta]), polygon(other)
            inter = mine.intersection(theirs).area
            turn = abs((theta - other[4] + np.pi / 2) % np.pi - np.pi / 2)
            hits += inter / (mine.area + theirs.area - inter) > 0.25 and turn <= np.radians(30)
        counts.append(hits)
    return counts


def test_consensus_target_is_the_grasp_that_hits_the_most_of_the_others():
    """A mug-like annotation: three grasps across a handle, beside three across the body at angles of their own:
    the target is a handle grasp, the first row with the most hits by shapely's IoU, and both parts answer it."""
    handle = _rows([(150, 100), (153, 100), (156, 101)], [0.05, 0.0, -0.04])
    body = _rows([(100, 100), (101, 99), (99, 101)], [-1.2, 0.9, 0.2])
    for order in (0, 1, 2):
        grasps = np.random.default_rng(order).permutation(np.concatenate([body, handle]))
        counts = shapely_hit_counts(grasps)
        (location, angle) = format_sample(_sample(grasps), FormatConfig(target_grasp="consensus"))
        assert location.grasp.tolist() == angle.grasp.tolist() == grasps[int(np.argmax(counts))].tolist()
        assert location.grasp[0] >= 150 and max(counts) == 3
        assert np.array_equal(location.answers, grasps)


def test_consensus_target_of_one_grasp_and_of_grasps_that_hit_none_of_each_other():
    (only,) = format_sample(_sample(_rows([(5, 7)], [0.3])), FormatConfig(target_grasp="consensus", individual=False))
    assert only.grasp[:2].tolist() == [5.0, 7.0]
    apart = _rows([(10, 50), (90, 50), (170, 50)], [0.0, 1.0, -1.0])  # each hits itself only: the first row
    assert shapely_hit_counts(apart) == [1, 1, 1]
    (first,) = format_sample(_sample(apart), FormatConfig(target_grasp="consensus", individual=False))
    assert first.grasp.tolist() == apart[0].tolist()


def test_centre_on_the_edge_prints_inside():
    grasp = np.array([[223.7, 0.2, 30.0, 10.0, 0.0]])
    (example,) = format_sample(_sample(grasp), FormatConfig(individual=False))
    assert example.value.startswith("Grasp center point coordinates: x_223,y_0 ")
    assert parse_target(example.target_text, "grasp", FormatConfig()).ok


@pytest.mark.parametrize("representation", grasp_text.REPRESENTATIONS)
@pytest.mark.parametrize("angle_code", [True, False])
def test_targets_are_grasp_texts_even_at_the_edges(representation, angle_code):
    """One clamping rule: the targets a build writes are grasp_text.format_grasp's text, split."""
    rng = np.random.default_rng(3)
    n = 400
    grasps = np.c_[rng.choice([-3.0, 0.0, 0.4, 223.4, 223.6, 224.0, 230.0], (n, 2)),
                   rng.choice([0.0, 0.3, 1.0, 447.6, 448.0, 1000.0], (n, 2)), rng.uniform(-np.pi / 2, np.pi / 2, n)]
    grasps[n // 2:, :4] = rng.uniform([-5, -5, 0, 0], [230, 230, 600, 600], (n - n // 2, 4))
    individual = FormatConfig(representation=representation, angle_code=angle_code, target_grasp="each")
    joint = FormatConfig(representation=representation, angle_code=angle_code, target_grasp="each", individual=False)
    locations = [e for e in format_sample(_sample(grasps), individual) if e.part == "location"]
    wholes = format_sample(_sample(grasps), joint)
    angle_length = [len(grasp_text.format_angle(g[4], angle_code)) + 1 for g in grasps]
    for grasp, location, whole, cut in zip(grasps, locations, wholes, angle_length):
        expected = grasp_text.format_grasp(grasp, representation, angle_code, SIZE)
        assert whole.target_text == expected
        assert location.target_text == expected[:-cut], grasp.tolist()


@pytest.mark.parametrize("loss_on", ["target", "instruction"])
@pytest.mark.parametrize("individual", [True, False])
def test_layout_and_loss_span(tokenizer, loss_on, individual):
    config = FormatConfig(individual=individual, loss_on=loss_on, max_length=160)
    for example in format_sample(_sample(_grasps(4, seed=2)), config):
        encoded = layout.encode_example(example, tokenizer, config)
        tokens, loss, image = encoded["tokens"], encoded["loss_mask"], encoded["image_mask"]
        length = int(encoded["length"])
        assert tokens.shape == loss.shape == image.shape == (160,)
        assert tokens[0] == tokenizer.bos_id and tokens[1] == tokenizer.image_start_id
        assert tokens[2 + special.IMAGE_SLOTS] == tokenizer.image_end_id
        assert np.flatnonzero(image).tolist() == list(range(2, 66))
        assert tokens[image].tolist() == list(range(4, 68))
        assert tokens[length - 1] == tokenizer.eos_id and np.all(tokens[length:] == tokenizer.pad_id)
        if loss_on == "target":
            expected = tokenizer.encode(example.value) + [tokenizer.eos_id]
        else:
            expected = tokens[layout.PREFIX_LENGTH : length].tolist()
        assert tokens[loss].tolist() == expected
        # the masked span is contiguous and ends at </s>
        positions = np.flatnonzero(loss)
        assert positions[-1] == length - 1 and np.all(np.diff(positions) == 1)
        assert tokenizer.decode(tokens[layout.text_span(encoded)]) == example.text
        assert not bool(encoded["truncated"])


def test_non_has_no_instruction_tokens(tokenizer):
    config = FormatConfig(individual=False)
    (example,) = format_sample(_sample(_grasps(1), kind="non", instruction=""), config)
    encoded = layout.encode_example(example, tokenizer, config)
    first_text = layout.PREFIX_LENGTH
    assert encoded["loss_mask"][first_text] and not encoded["loss_mask"][first_text - 1]


def test_overflow_error_and_truncation(tokenizer):
    long_instruction = "Grasp the " + "very " * 80 + "long object."
    sample = _sample(_grasps(1), instruction=long_instruction)
    config = FormatConfig(max_length=100)
    (example, _) = format_sample(sample, config)
    with pytest.raises(layout.SequenceTooLongError, match=r"pcd0100.*max_length=100"):
        layout.encode_example(example, tokenizer, config)
    cut = FormatConfig(max_length=100, overflow="truncate")
    encoded = layout.encode_example(example, tokenizer, cut)
    assert bool(encoded["truncated"]) and int(encoded["length"]) == 100
    assert encoded["tokens"].shape == (100,)


@pytest.mark.parametrize(
    "settings, message",
    [
        ({"representation": "xyz"}, "unknown grasp representation 'xyz'"),
        ({"loss_on": "all"}, "unknown loss_on 'all'"),
        ({"overflow": "drop"}, "unknown overflow 'drop'"),
        ({"target_grasp": "best"}, "unknown target_grasp 'best'"),
        ({"image_size": 0}, "image_size"),
    ],
)
def test_bad_settings(settings, message):
    with pytest.raises(ValueError, match=message):
        FormatConfig(**settings)


def test_bad_inputs(tokenizer):
    with pytest.raises(ValueError, match="pcd0100.*no grasps"):
        format_sample(_sample(np.zeros((0, 5))), FormatConfig())
    with pytest.raises(ValueError, match="unknown answer 'box'"):
        format_sample(_sample(_grasps(1), answer="box"), FormatConfig())
    with pytest.raises(ValueError, match="unknown part"):
        parse_target("x", "size", FormatConfig())
    (example, _) = format_sample(_sample(_grasps(1)), FormatConfig())
    with pytest.raises(ValueError, match="max_length=40"):
        layout.encode_example(example, tokenizer, FormatConfig(max_length=40))


def test_parts_are_checked_by_name():
    assert [check_part(part) for part in ("grasp", "location", "angle")] == ["grasp", "location", "angle"]
    with pytest.raises(ValueError, match=r"unknown part 'size'; expected one of \('grasp', 'location', 'angle'\)"):
        check_part("size")


def test_target_text_joins_cue_and_value():
    assert target_text("Grasp center point coordinates:", "x_1,y_2") == "Grasp center point coordinates: x_1,y_2"
    assert target_text("", "x_1,y_2 a_3") == "x_1,y_2 a_3"  # joint mode: no cue
    for example in format_sample(_sample(_grasps(2)), FormatConfig()):
        assert example.target_text == target_text(example.cue, example.value)


def test_image_tags_occur_once_per_prompt(tokenizer):
    config = FormatConfig(max_length=160)
    for example in format_sample(_sample(_grasps(3, seed=5)), config):
        encoded = layout.encode_example(example, tokenizer, config)
        tokens = encoded["tokens"][: int(encoded["length"])].tolist()
        assert tokens.count(tokenizer.image_start_id) == 1 and tokens.count(tokenizer.image_end_id) == 1
        # the slot ids are exactly the masked positions
        in_slot_range = np.isin(encoded["tokens"], special.IMAGE_SLOT_IDS)
        assert np.array_equal(in_slot_range, encoded["image_mask"])
