"""Constrained generation end to end: the project's SentencePiece tokenizer, the tiny model with
random weights, generation.generate: every decoded answer parses, for every representation, whole
(joint mode) or as the value after a cue that ends the prompt (individual mode)."""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax import grasp_text
from kosmos_jax.models import generation, weights
from kosmos_jax.models.grammar import TokenConstraint, cue_constraints
from kosmos_jax.text import formatter
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


INSTRUCTIONS = ("Grasp the black remote control.", "Grasp the handle of the mug.", "Grasp it.",
                "Grasp the object with a rotation angle of a_156 radians.")


def prompts(tokenizer, slots: int, cue: str = ""):
    """ROWS left-padded prompts <s><image> slots </image> instruction cue, each text encoded on its
    own as layout.py does: (ids, mask, image_mask)."""
    cue_ids = tokenizer.encode(cue) if cue else []
    rows = [[tokenizer.bos_id, tokenizer.image_start_id, *special.IMAGE_SLOT_IDS[:slots], tokenizer.image_end_id,
             *tokenizer.encode(text), *cue_ids] for text in INSTRUCTIONS[:ROWS]]
    length = max(map(len, rows))
    ids = np.full((ROWS, length), tokenizer.pad_id, np.int32)
    mask, image_mask = np.zeros(ids.shape, bool), np.zeros(ids.shape, bool)
    for r, row in enumerate(rows):
        pad = length - len(row)
        ids[r, pad:], mask[r, pad:] = row, True
        image_mask[r, pad + 2:pad + 2 + slots] = True
    return jnp.asarray(ids), jnp.asarray(mask), jnp.asarray(image_mask)


def vocabulary_texts(tokenizer, model):
    return tokenizer.piece_texts() + [""] * (model.config.text.vocab_size - tokenizer.vocab_size)


def constrained_rows(tokenizer, model, constraint, cue="", seeds=3):
    """The generated ids of ROWS prompts (ending with `cue`) for each seed's random weights and
    image embeddings, under `constraint`, up to the EOS every row must have."""
    ids, mask, image_mask = prompts(tokenizer, model.config.latent_query_num, cue)
    slots = model.config.latent_query_num
    table = model.text_model.model.embed_tokens.embedding
    answers = []
    for seed in range(seeds):
        weights_key, image_key = jax.random.split(jax.random.key(seed))
        table.set_value(jax.random.normal(weights_key, table.shape))  # the tied LM head: random logits
        embeds = jax.random.normal(image_key, (ROWS, slots, model.config.text.embed_dim))
        # a budget a few tokens over the shortest answer, so the budget often decides
        tokens = generation.generate(model, ids, mask, image_mask, embeds, max_new_tokens=constraint.min_tokens + 6,
                                 constraint=constraint)
        for row in np.asarray(tokens).tolist():
            assert tokenizer.eos_id in row, row
            answers.append(row[:row.index(tokenizer.eos_id)])
    return answers


CASES = ([("digits", r, True) for r in grasp_text.REPRESENTATIONS]
         + [("digits", "xya", False), ("digits", "tlbra", False)]
         + [("values", r, True) for r in ("xya", "xywha", "tlbra")])


@pytest.mark.parametrize("numbers,representation,angle_code", CASES)
def test_every_decoded_answer_parses(tokenizers, model, numbers, representation, angle_code):
    tokenizer = tokenizers[numbers]
    constraint = TokenConstraint(vocabulary_texts(tokenizer, model), tokenizer.eos_id, representation,
                                 angle_code=angle_code, image_size=SIZE)
    answers = [tokenizer.decode(row) for row in constrained_rows(tokenizer, model, constraint)]
    for text in answers:
        parsed = grasp_text.parse_grasp(text, representation, angle_code=angle_code, image_size=SIZE)
        assert parsed.ok, (text, parsed.error)
    assert len(set(answers)) > 1  # the rows and seeds do not all say the same


# individual mode: every representation's location, the angle with and without the code
PART_CASES = ([("digits", r, True, "location") for r in grasp_text.REPRESENTATIONS]
              + [("digits", "xya", code, "angle") for code in (True, False)]
              + [("values", "xya", True, part) for part in ("location", "angle")])


@pytest.mark.parametrize("numbers,representation,angle_code,part", PART_CASES)
def test_every_value_decoded_after_its_cue_parses(tokenizers, model, numbers, representation, angle_code, part):
    """Prompts end with the part's cue, as in individual mode; the value decoded under the part's
    constraint makes, after the cue, a target text formatter.parse_target accepts."""
    tokenizer = tokenizers[numbers]
    config = formatter.FormatConfig(representation, angle_code, individual=True, image_size=SIZE)
    prompt = {p.part: p for p in cue_constraints(vocabulary_texts(tokenizer, model), tokenizer.eos_id, config)}[part]
    texts = []
    for row in constrained_rows(tokenizer, model, prompt.constraint, prompt.cue, seeds=2):
        text = prompt.target_text(row)
        parsed = formatter.parse_target(text, part, config)
        assert parsed.ok, (text, parsed.error)
        # the tokenizer reads the same value (its decode may keep a byte piece's leading space)
        assert tokenizer.decode(row).removeprefix(" ") == prompt.constraint.answer(row)
        texts.append(text)
    assert len(set(texts)) > 1
