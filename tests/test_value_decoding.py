"""Reading coordinate value tokens, and angle tokens around the circle, as the local mean of the model's
distribution (models.value_decoding)."""

import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.models.value_decoding import LocalMean, greedy, value_picker

PIECES = ["<s>", "</s>", "Grasp", *[f"x_{v}" for v in range(20)], *[f"y_{v}" for v in range(20)], "a_0", "a_1", "a_2"]
ID = {piece: i for i, piece in enumerate(PIECES)}


def _logits(probabilities: dict[str, float]) -> np.ndarray:
    """One row of logits whose softmax over the named tokens is `probabilities` (others ~0)."""
    row = np.full(len(PIECES), -1e4, np.float32)
    for piece, p in probabilities.items():
        row[ID[piece]] = np.log(p)
    return row


def _pick(window, rows, allowed=None):
    logits = jnp.asarray(np.stack(rows))
    allowed = jnp.ones(logits.shape, bool) if allowed is None else jnp.asarray(allowed)
    return [PIECES[i] for i in np.asarray(LocalMean(PIECES, window).pick(logits, allowed))]


def test_the_local_mean_of_the_modes_family_within_the_window_is_answered():
    bump = {"x_4": 0.2, "x_5": 0.3, "x_8": 0.25, "x_15": 0.15, "y_6": 0.1}
    near = {k: v for k, v in bump.items() if k.startswith("x_") and abs(int(k[2:]) - 5) <= 3}
    mean = sum(int(k[2:]) * v for k, v in near.items()) / sum(near.values())  # 5.93: x_15 lies outside, y_6 is another family
    assert _pick(3, [_logits(bump)]) == [f"x_{round(mean)}"]
    wide = {k: v for k, v in bump.items() if k.startswith("x_")}
    assert _pick(19, [_logits(bump)]) == [f"x_{round(sum(int(k[2:]) * v for k, v in wide.items()) / sum(wide.values()))}"]


def test_window_zero_angles_and_words_are_greedy():
    rows = [_logits({"x_4": 0.4, "x_9": 0.35, "x_10": 0.25}), _logits({"a_0": 0.5, "a_2": 0.5 - 1e-3}),
            _logits({"Grasp": 0.6, "x_3": 0.4})]
    modes = np.asarray(greedy(jnp.asarray(np.stack(rows)), jnp.ones((3, len(PIECES)), bool)))
    assert [PIECES[i] for i in modes] == _pick(0, rows) == ["x_4", "a_0", "Grasp"]
    assert _pick(8, rows) == ["x_7", "a_0", "Grasp"]  # 4 * 0.4 + 9 * 0.35 + 10 * 0.25 = 7.25


def test_only_allowed_tokens_count_and_a_disallowed_mean_keeps_the_mode():
    row = _logits({"x_2": 0.4, "x_3": 0.1, "x_6": 0.3, "x_7": 0.2})
    allowed = np.ones((1, len(PIECES)), bool)
    allowed[0, ID["x_7"]] = False
    # x_7 not allowed: mean of x_2, x_3, x_6 = (0.8 + 0.3 + 1.8) / 0.8 = 3.625 -> x_4
    assert _pick(5, [row], allowed) == ["x_4"]
    allowed[0, ID["x_4"]] = False
    assert _pick(5, [row], allowed) == ["x_2"]


def test_a_vocabulary_without_value_tokens_and_a_padded_vocabulary():
    words = ["<s>", "</s>", "Grasp", "1", "2"]
    logits = jnp.asarray(np.array([[0.0, 0.0, 3.0, 1.0, 2.0]], np.float32))
    assert np.asarray(LocalMean(words, 8).pick(logits, jnp.ones((1, 5), bool))).tolist() == [2]
    padded = np.concatenate([_logits({"y_10": 0.5, "y_12": 0.5 - 1e-3}), np.full(3, -1e4, np.float32)])[None]
    token = LocalMean(PIECES, 4).pick(jnp.asarray(padded), jnp.ones(padded.shape, bool))
    assert PIECES[int(token[0])] == "y_11"


def test_a_negative_window_is_refused():
    with pytest.raises(ValueError, match="value window"):
        LocalMean(PIECES, -1)


def test_a_window_of_zero_gives_no_picker():
    assert value_picker(PIECES, 0) is None and isinstance(value_picker(PIECES, 4), LocalMean)


ANGLES = ["<s>", "</s>", *[f"x_{v}" for v in range(20)], *[f"a_{k}" for k in range(256)]]
ANGLE_ID = {piece: i for i, piece in enumerate(ANGLES)}


def _angle_pick(window, angle_window, probabilities, allowed=None):
    row = np.full(len(ANGLES), -1e4, np.float32)
    for piece, p in probabilities.items():
        row[ANGLE_ID[piece]] = np.log(p)
    allowed = np.ones((1, len(ANGLES)), bool) if allowed is None else allowed
    picked = LocalMean(ANGLES, window, angle_window).pick(jnp.asarray(row[None]), jnp.asarray(allowed))
    return ANGLES[int(picked[0])]


def test_an_angle_is_read_as_the_circular_local_mean_of_its_bins():
    bump = {"a_100": 0.4, "a_104": 0.35, "a_140": 0.25}
    assert _angle_pick(0, 0, bump) == "a_100"  # no angle window: the mode
    # within 8 bins of the mode: (0 * 0.4 + 4 * 0.35) / 0.75 = 1.87 bins past it; a_140 lies outside
    assert _angle_pick(0, 8, bump) == "a_102"
    assert _angle_pick(0, 64, bump) == f"a_{round(100 + (4 * 0.35 + 40 * 0.25) / 1.0)}"
    # a_255 and a_0 are neighbours (the same grasp axis): the mean of a_254 and a_2 falls between them
    wrap = {"a_254": 0.5, "a_2": 0.5 - 1e-3}
    assert _angle_pick(0, 8, wrap) == "a_0"
    assert _angle_pick(0, 8, {"a_253": 0.6, "a_1": 0.4}) == "a_255"  # a_1 is 4 bins past a_253: 1.6 past it
    # the coordinate window leaves angles alone, the angle window leaves coordinates alone
    assert _angle_pick(8, 0, bump) == "a_100" and _angle_pick(0, 8, {"x_4": 0.5, "x_6": 0.5 - 1e-3}) == "x_4"


def test_a_disallowed_angle_mean_keeps_the_mode_and_bad_angle_windows_are_refused():
    allowed = np.ones((1, len(ANGLES)), bool)
    allowed[0, ANGLE_ID["a_102"]] = False
    assert _angle_pick(0, 8, {"a_100": 0.4, "a_104": 0.35}, allowed) == "a_100"
    for bad in (-1, 128):
        with pytest.raises(ValueError, match="angle window"):
            LocalMean(ANGLES, 0, bad)
    assert value_picker(ANGLES, 0, 0) is None and value_picker(ANGLES, 0, 16).angle_window == 16
