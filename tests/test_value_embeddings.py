"""model.value_token_code: value tokens' embeddings that start near each other for near values."""

import numpy as np
import pytest

from configs import kosmos_e
from kosmos_jax.models import config as model_configs
from kosmos_jax.models.value_embeddings import (VALUE_TOKEN, angle_harmonic_width, value_code, value_phases, value_rows,
                                                with_value_code)
from kosmos_jax.text.tokenizer import train_tokenizer
from kosmos_jax.train import trainer

TEXTS = ["Grasp center point coordinates: x_24,y_191", "Grasp rotation angle in radians: a_195", "Grasp the mug."]


def test_codes_are_unit_rows_whose_likeness_falls_with_the_distance_of_their_values():
    code = value_code(value_phases("x", np.arange(224.0)), 128)
    np.testing.assert_allclose(np.linalg.norm(code, axis=1), 1.0, rtol=1e-6)
    likeness = code @ code[100]
    near = likeness[100:121]  # x_100 .. x_120
    assert (np.diff(near) < 0).all(), near  # falls with every pixel over the first 20
    assert near[1] > 0.9 and near[20] < 0.3
    assert np.abs(likeness[:60]).max() < 0.1  # far values are unrelated, not opposite
    assert likeness[0] < 0.1 and likeness[223] < 0.1  # pixel values do not wrap round


def test_angle_codes_wrap_round():
    codes = value_code(value_phases("a", np.array([0.0, 1.0, 128.0, 255.0])), 64)
    assert codes[0] @ codes[3] == pytest.approx(codes[0] @ codes[1], rel=1e-6)  # a_255 is a_0's neighbour
    assert abs(codes[0] @ codes[2]) < 0.1


def test_a_wide_angle_kernel_keeps_bins_alike_over_its_width_and_leaves_other_families_alone():
    phases = value_phases("a", np.arange(256.0))
    sharp, wide = value_code(phases, 128), value_code(phases, 128, angle_harmonic_width(20.0))
    np.testing.assert_allclose(np.linalg.norm(wide, axis=1), 1.0, rtol=1e-6)
    assert sharp[0] @ sharp[10] < 0.1 < 0.8 < wide[0] @ wide[10]  # 10 bins: unlike by default, alike when wide
    assert 0.3 < wide[0] @ wide[20] < 0.7 and wide[0] @ wide[128] < 0  # about 20 bins; a right angle apart
    pieces = ["", "x_10", "a_0", "a_10"]
    table = np.zeros((4, 128), np.float32)
    default, widened = with_value_code(table, pieces, 1.0), with_value_code(table, pieces, 1.0, angle_kernel_bins=20.0)
    np.testing.assert_array_equal(default[1], widened[1])  # x keeps its code
    assert default[2] @ default[3] < 0.1 < 0.8 < widened[2] @ widened[3]
    with pytest.raises(ValueError, match="angle_kernel_bins"):
        with_value_code(table, pieces, 1.0, angle_kernel_bins=-1.0)
    with pytest.raises(ValueError, match="harmonic width"):
        value_code(phases, 128, 0.0)


def test_value_rows_finds_every_value_token_and_nothing_else():
    pieces = ["", "x_0", "x_223", "y_5", "a_255", "w_12", "h_-3", "x_", "x_1a", " x_2", "Grasp", "a"]
    rows = value_rows(pieces)
    assert {family: ids.tolist() for family, (ids, _) in rows.items()} == {
        "x": [1, 2], "y": [3], "a": [4], "w": [5], "h": [6]}
    np.testing.assert_allclose(rows["x"][1], [0.0, np.pi * 223 / 224])


def test_a_range_below_zero_spans_half_a_turn_so_its_ends_stay_apart():
    """tlbra's corners run from -224 to 448: each family's phases come from its own range."""
    _, phases = value_rows(["x_-224", "x_224", "x_448"])["x"]
    codes = value_code(phases, 128)
    assert abs(codes[0] @ codes[1]) < 0.1 and abs(codes[0] @ codes[2]) < 0.1  # a 224 px turn would make x_224 x_-224


def test_with_value_code_adds_the_code_to_value_rows_only():
    rng = np.random.default_rng(0)
    table = rng.normal(size=(6, 8)).astype(np.float32)
    pieces = ["", "Grasp", "x_10", "x_11", "y_10", "a_3"]
    out = with_value_code(table, pieces, 2.0)
    np.testing.assert_array_equal(out[:2], table[:2])
    added = out[2:] - table[2:]
    np.testing.assert_allclose(np.linalg.norm(added, axis=1), 2.0, rtol=1e-5)
    np.testing.assert_allclose(added[0], added[2], atol=1e-6)  # x_10 and y_10 get one code ...
    assert not np.allclose(out[2], out[4])  # ... and stay apart by their random rows
    np.testing.assert_array_equal(table, np.random.default_rng(0).normal(size=(6, 8)).astype(np.float32))  # input kept
    with pytest.raises(ValueError, match="numbers=values"):
        with_value_code(table, ["", "Grasp", "x", "_", "1", "2"], 1.0)
    with pytest.raises(ValueError, match="even width"):
        value_code(np.zeros(2), 7)


def _tiny_config(code: float):
    config = kosmos_e.get_config("tiny")
    config.model.value_token_code = code
    return config


@pytest.mark.slow  # 19 s (make test's --durations, 2026-11-28, 2 cores)
def test_fresh_parameters_start_with_near_values_near_and_digit_tokenizers_are_refused():
    values = train_tokenizer(TEXTS, numbers="values", text_pieces=50)
    cfg = model_configs.TINY.with_vocab_size(values.vocab_size)
    ids = [values.token_id(t) for t in ("x_60", "x_61", "x_200")]

    def rows(code):
        params = trainer.initial_params(_tiny_config(code), cfg, values, None, {})
        table = np.asarray(params["text_model"]["model"]["embed_tokens"]["embedding"].get_value())
        return table / np.linalg.norm(table, axis=1, keepdims=True)

    plain, coded = rows(0.0), rows(3.0)
    x60, x61, x200 = coded[ids]
    assert x60 @ x61 > 0.7 and abs(x60 @ x200) < 0.3
    assert abs(plain[ids[0]] @ plain[ids[1]]) < 0.5  # random rows: no such likeness without the code
    others = [i for i, piece in enumerate(values.piece_texts()) if not VALUE_TOKEN.match(piece)]
    np.testing.assert_array_equal(coded[others], plain[others])  # every other row as built

    digits = train_tokenizer(TEXTS, numbers="digits", text_pieces=50)
    with pytest.raises(ValueError, match="numbers=values"):
        trainer.initial_params(_tiny_config(1.0), model_configs.TINY.with_vocab_size(digits.vocab_size), digits,
                               None, {})


def test_the_code_is_refused_over_kosmos_2_weights():
    config = _tiny_config(1.0)
    config.init_from = "/nonexistent"
    values = train_tokenizer(TEXTS, numbers="values", text_pieces=50)
    with pytest.raises(ValueError, match="value_token_code"):
        trainer.initial_params(config, model_configs.TINY.with_vocab_size(values.vocab_size), values, None, {})
