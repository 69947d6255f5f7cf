"""Tokenizers: trained (native ids) and loaded (fairseq ids), value tokens, round trips, errors."""

import io
import re

import numpy as np
import pytest
import sentencepiece as spm

from kosmos_jax import grasp_text
from kosmos_jax.text import tokens as special
from kosmos_jax.text.tokenizer import Tokenizer, fairseq_layout, load_tokenizer, train_tokenizer


def _grasps(n=40, size=224, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack(
        [rng.uniform(0, size, n), rng.uniform(0, size, n), rng.uniform(5, 80, n), rng.uniform(5, 40, n), rng.uniform(-np.pi / 2, np.pi / 2, n)],
        axis=1,
    )


def _corpus(representation="xya"):
    texts = ["Grasp the black remote control.", "Grasp the handle of the mug.", "Grasp the object with a rotation angle of a_156 radians."]
    texts += [grasp_text.format_grasp(g, representation) for g in _grasps()]
    return texts


@pytest.fixture(scope="module")
def digits_tokenizer():
    return train_tokenizer(_corpus(), numbers="digits", text_pieces=200)


@pytest.fixture(scope="module")
def values_tokenizer():
    return train_tokenizer(_corpus("xywha"), numbers="values", text_pieces=200, representations=("xya", "xywha", "tlbra"))


@pytest.mark.parametrize(
    "text",
    [
        "Grasp the black remote control.",
        "Grasp center point coordinates: x_12,y_105 Grasp rotation angle in radians: a_77",
        "Grasp bounding box: <patch_index_0012><patch_index_1023> Grasp rotation angle in radians: a_-0.52",
        "Grasp the zebra-striped Ümlaut cup (never seen) 😀",
        "<image></image>Grasp",
    ],
)
def test_round_trip(digits_tokenizer, values_tokenizer, text):
    for tokenizer in (digits_tokenizer, values_tokenizer):
        assert tokenizer.decode(tokenizer.encode(text)) == text
        assert tokenizer.unk_id not in tokenizer.encode(text)  # byte fallback, never <unk>


def test_training_is_deterministic():
    a = train_tokenizer(_corpus(), text_pieces=100)
    b = train_tokenizer(_corpus(), text_pieces=100)
    assert a.model_proto == b.model_proto


def test_native_special_ids(digits_tokenizer):
    t = digits_tokenizer
    assert (t.bos_id, t.pad_id, t.eos_id, t.unk_id) == (0, 1, 2, 3)
    sp = spm.SentencePieceProcessor(model_proto=t.model_proto)
    assert [sp.id_to_piece(i) for i in range(4)] == ["<s>", "<pad>", "</s>", "<unk>"]
    for symbol in ("<image>", "</image>", "<patch_index_0000>", "<patch_index_1023>"):
        assert t.encode(symbol)[-1] == t.token_id(symbol)  # one piece, maybe after a "▁"
        assert t.pieces(symbol)[-1] == symbol
    assert t.vocab_size > max(special.IMAGE_SLOT_IDS)


_VALUE = re.compile(r"[xywha]_-?\d+")
_BYTE = re.compile(r"<0x[0-9A-F]{2}>")


@pytest.mark.parametrize("representation", ["xya", "xywha", "tlbra"])
def test_value_tokens_one_token_per_value(values_tokenizer, representation):
    for grasp in _grasps(30, seed=1):
        text = grasp_text.format_grasp(grasp, representation)
        values = _VALUE.findall(text)
        pieces = values_tokenizer.pieces(text)
        assert [p for p in pieces if _VALUE.fullmatch(p)] == values, text
        text_pieces = [p for p in pieces if not _VALUE.fullmatch(p) and not _BYTE.fullmatch(p)]
        assert not any(re.search(r"\d", p) for p in text_pieces), pieces


def test_digits_mode_splits_numbers(digits_tokenizer):
    pieces = digits_tokenizer.pieces("Grasp center point coordinates: x_123,y_45 Grasp rotation angle in radians: a_200")
    digit_pieces = [p for p in pieces if re.search(r"\d", p)]
    assert digit_pieces and all(re.fullmatch(r"\d", p) for p in digit_pieces)
    assert "x_123" not in pieces


def test_save_and_load_native(tmp_path, values_tokenizer):
    path = values_tokenizer.save(tmp_path / "spm.model")
    loaded = load_tokenizer(path, scheme="native", numbers="values")
    text = "Grasp center point coordinates: x_3,y_200 Grasp rotation angle in radians: a_9"
    assert loaded.encode(text) == values_tokenizer.encode(text)


def _plain_spm(tmp_path):
    """A small model laid out like KOSMOS-2's: SentencePiece defaults <unk>=0, <s>=1, </s>=2."""
    model = io.BytesIO()
    texts = ["Grasp the black remote control.", "Grasp center point coordinates: x_12,y_105"] * 10
    spm.SentencePieceTrainer.train(sentence_iterator=iter(texts), model_writer=model, vocab_size=60, hard_vocab_limit=False, minloglevel=2, num_threads=1)
    path = tmp_path / "sentencepiece.bpe.model"
    path.write_bytes(model.getvalue())
    return path, spm.SentencePieceProcessor(model_proto=model.getvalue())


def test_fairseq_scheme_shift(tmp_path):
    path, sp = _plain_spm(tmp_path)
    n = sp.get_piece_size()
    t = load_tokenizer(path, scheme="fairseq")
    assert (t.bos_id, t.pad_id, t.eos_id, t.unk_id) == (0, 1, 2, 3)
    text = "Grasp the remote control"
    assert t.encode(text) == [i + 1 for i in sp.encode(text)]  # every ordinary piece shifted by one
    layout = fairseq_layout(n)
    for symbol in ("<image>", "</image>", "<grounding>", "<patch_index_0000>", "<patch_index_1023>"):
        assert t.token_id(symbol) == layout[symbol]
    assert t.image_start_id == n + 3 and t.image_end_id == n + 4
    assert t.vocab_size == n + 2 + len(special.SPECIAL_SYMBOLS)
    mixed = "Grasp <image> the <patch_index_0007><patch_index_0100> control"
    assert t.decode(t.encode(mixed)) == mixed
    assert t.decode([t.bos_id] + t.encode(text) + [t.eos_id]) == text


def test_piece_texts_spell_what_the_tokenizer_decodes(digits_tokenizer, values_tokenizer, tmp_path):
    answer = grasp_text.format_grasp([12, 200, 30, 20, -0.52], "xya", angle_code=False)
    fairseq = load_tokenizer(_plain_spm(tmp_path)[0], scheme="fairseq")  # no byte pieces: plain text only
    cases = [(digits_tokenizer, (answer, "Grasp {it} (quickly) ~now~")),  # unseen ASCII characters: byte pieces
             (values_tokenizer, (answer,)), (fairseq, ("Grasp the remote control <patch_index_0007>",))]
    for tokenizer, texts_in in cases:
        texts = tokenizer.piece_texts()
        assert len(texts) == tokenizer.vocab_size
        assert texts[tokenizer.eos_id] == texts[tokenizer.bos_id] == texts[tokenizer.pad_id] == ""
        assert texts[tokenizer.token_id("<patch_index_0012>")] == "<patch_index_0012>"
        for text in texts_in:
            ids = tokenizer.encode(text)
            assert "".join(texts[i] for i in ids) == " " + text  # SentencePiece's leading space, as "▁"
    texts = digits_tokenizer.piece_texts()
    assert all(texts[i] == "" for i in special.IMAGE_SLOT_IDS)  # control pieces
    assert "".join(texts[i] for i in digits_tokenizer.encode("cup Ü")) == " cup "  # non-ASCII bytes spell nothing
    assert fairseq.piece_texts()[fairseq.vocab_size - len(special.SPECIAL_SYMBOLS) - 1] == ""  # <mask>


def test_fairseq_layout_matches_kosmos2():
    layout = fairseq_layout(64000)
    assert layout["<image>"] == 64003 and layout["</image>"] == 64004 and layout["<grounding>"] == 64012
    assert layout["<patch_index_0000>"] == 64013 and layout["<patch_index_1023>"] == 65036
    assert max(layout.values()) + 1 == 65037


def test_errors(tmp_path, digits_tokenizer):
    with pytest.raises(ValueError, match="unknown number mode 'words'"):
        train_tokenizer(["a"], numbers="words")
    with pytest.raises(ValueError, match="no text"):
        train_tokenizer([])
    with pytest.raises(ValueError, match="unknown tokenizer scheme 'hf'"):
        Tokenizer(digits_tokenizer.model_proto, scheme="hf")
    with pytest.raises(FileNotFoundError, match="nope.model"):
        load_tokenizer(tmp_path / "nope.model")
    junk = tmp_path / "junk.model"
    junk.write_bytes(b"\x00\xffnot a model")
    with pytest.raises(ValueError, match="junk.model"):
        load_tokenizer(junk)
    native = digits_tokenizer.save(tmp_path / "native.model")
    with pytest.raises(ValueError, match="pieces 0..2"):
        load_tokenizer(native, scheme="fairseq")
    path, _ = _plain_spm(tmp_path)
    with pytest.raises(ValueError, match="value tokens"):
        load_tokenizer(path, scheme="fairseq", numbers="values")
    with pytest.raises(KeyError, match="x_999"):
        digits_tokenizer.token_id("x_999")


def test_trained_tokenizer_reserves_the_image_slot_ids(digits_tokenizer, values_tokenizer, tmp_path):
    for t in (digits_tokenizer, values_tokenizer):
        assert t.reserves_image_slots
        slots = set(special.IMAGE_SLOT_IDS)
        assert not slots & {t.token_id(s) for s in special.SPECIAL_SYMBOLS}  # no tag or patch token
        assert min(t.token_id(s) for s in special.SPECIAL_SYMBOLS) == special.FIRST_SLOT_ID + special.IMAGE_SLOTS
        for text in _corpus() + ["<image_slot_03> <image></image><patch_index_0001>", "Grasp the cup 😀"]:
            assert not slots & set(t.encode(text)), text  # text never produces a slot id
        assert t.decode(list(special.IMAGE_SLOT_IDS) + t.encode("Grasp the cup.")) == "Grasp the cup."
        assert load_tokenizer(t.save(tmp_path / "t.model"), scheme="native").reserves_image_slots


def test_kosmos2_layout_keeps_its_slots_as_ordinary_pieces(tmp_path):
    path, sp = _plain_spm(tmp_path)
    t = load_tokenizer(path, scheme="fairseq")
    assert not t.reserves_image_slots  # KOSMOS-2's scheme: ids 4..67 are pieces 3..66, as its code has it
    assert t.encode("Grasp the remote control")[0] in special.IMAGE_SLOT_IDS  # text shares those ids
