"""Constrained generation end to end: the project's SentencePiece tokenizer, the tiny model with
random weights, decode.generate: every decoded answer parses, for every representation."""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax import grasp_text
from kosmos_jax.models import decode, weights
from kosmos_jax.models.grammar import TokenConstraint, token_texts
from kosmos_jax.text import tokens as special
from kosmos_jax.text.tokenizer import train_tokenizer

FIXTURE = pathlib.Path(__file__).parent / "fixtures" / "kosmos2_tiny"
SIZE = 224
ROWS = 4


def corpus():
    rng = np.random.default_rng(0)
    texts = ["Grasp the black remote control.", "Grasp the handle of the mug."]
    for representation in grasp_text.REPRESENTATIONS:
        for angle_code in (True, False):
            for _ in range(10):
                grasp = [*rng.uniform(0, SIZE - 1, 2), *rng.uniform(1, 150, 2), rng.uniform(-np.pi / 2, np.pi / 2)]
                texts.append(grasp_text.format_grasp(grasp, representation, angle_code, SIZE))
    return texts


@pytest.fixture(scope="module")
def tokenizers():
    texts = corpus()
    return {"digits": train_tokenizer(texts, numbers="digits", text_pieces=200),
            "values": train_tokenizer(texts, numbers="values", text_pieces=200,
                                      representations=grasp_text.REPRESENTATIONS)}


@pytest.fixture(scope="module")
def model(tokenizers):
    """The tiny KOSMOS-2 with its vocabulary grown to the tokenizers' (weights re-drawn per test)."""
    model = weights.load_pretrained(FIXTURE)
    model.eval()
    return weights.grow_vocabulary(model, max(t.vocab_size for t in tokenizers.values()))


def test_token_texts_spell_what_the_tokenizer_decodes(tokenizers):
    for tokenizer in tokenizers.values():
        texts = token_texts(tokenizer)
        assert len(texts) == tokenizer.vocab_size
        assert texts[tokenizer.eos_id] == "" and texts[tokenizer.token_id("<patch_index_0012>")] == "<patch_index_0012>"
        answer = grasp_text.format_grasp([12, 200, 30, 20, -0.52], "xya", angle_code=False)
        ids = tokenizer.encode(answer)
        assert "".join(texts[i] for i in ids) == " " + answer  # SentencePiece's leading space, as "▁"


INSTRUCTIONS = ("Grasp the black remote control.", "Grasp the handle of the mug.", "Grasp it.",
                "Grasp the object with a rotation angle of a_156 radians.")


def prompts(tokenizer, slots: int):
    """ROWS left-padded prompts <s><image> slots </image> instruction: (ids, mask, image_mask)."""
    rows = [[tokenizer.bos_id, tokenizer.image_start_id, *special.IMAGE_SLOT_IDS[:slots], tokenizer.image_end_id,
             *tokenizer.encode(text)] for text in INSTRUCTIONS[:ROWS]]
    length = max(map(len, rows))
    ids = np.full((ROWS, length), tokenizer.pad_id, np.int32)
    mask, image_mask = np.zeros(ids.shape, bool), np.zeros(ids.shape, bool)
    for r, row in enumerate(rows):
        pad = length - len(row)
        ids[r, pad:], mask[r, pad:] = row, True
        image_mask[r, pad + 2:pad + 2 + slots] = True
    return jnp.asarray(ids), jnp.asarray(mask), jnp.asarray(image_mask)


CASES = ([("digits", r, True) for r in grasp_text.REPRESENTATIONS]
         + [("digits", "xya", False), ("digits", "tlbra", False)]
         + [("values", r, True) for r in ("xya", "xywha", "tlbra")])


@pytest.mark.parametrize("numbers,representation,angle_code", CASES)
def test_every_decoded_answer_parses(tokenizers, model, numbers, representation, angle_code):
    tokenizer = tokenizers[numbers]
    vocab_size = model.config.text.vocab_size
    texts = token_texts(tokenizer) + [""] * (vocab_size - tokenizer.vocab_size)
    constraint = TokenConstraint(texts, tokenizer.eos_id, representation, angle_code=angle_code, image_size=SIZE)
    ids, mask, image_mask = prompts(tokenizer, model.config.latent_query_num)
    slots = model.config.latent_query_num
    table = model.text_model.model.embed_tokens.embedding
    answers = set()
    for seed in range(3):
        weights_key, image_key = jax.random.split(jax.random.key(seed))
        table.set_value(jax.random.normal(weights_key, table.shape))  # the tied LM head: random logits
        embeds = jax.random.normal(image_key, (ROWS, slots, model.config.text.embed_dim))
        # a budget a few tokens over the shortest answer, so the budget often decides
        tokens = decode.generate(model, ids, mask, image_mask, embeds, max_new_tokens=constraint.min_tokens + 6,
                                 constraint=constraint)
        for row in np.asarray(tokens).tolist():
            assert tokenizer.eos_id in row, row
            text = tokenizer.decode(row[:row.index(tokenizer.eos_id)])
            parsed = grasp_text.parse_grasp(text, representation, angle_code=angle_code, image_size=SIZE)
            assert parsed.ok, (text, parsed.error)
            answers.add(text)
    assert len(answers) > 1  # the rows and seeds do not all say the same
