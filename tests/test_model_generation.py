"""Greedy decoding: the KV cache changes nothing, left padding changes nothing, and it matches transformers."""

import pathlib

import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.models import generation, weights
from kosmos_jax.models.kosmos2 import forward

FIXTURE = pathlib.Path(__file__).parent / "fixtures" / "kosmos2_tiny"
NEW = 4


@pytest.fixture(scope="module")
def setup():
    ref = dict(np.load(FIXTURE / "reference.npz"))
    model = weights.load_pretrained(FIXTURE)
    model.eval()
    args = (jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool),
            jnp.asarray(ref["image_embeds_position_mask"], bool), jnp.asarray(ref["image_embeds"]))
    return model, ref, args


def test_cached_and_uncached_decoding_agree(setup):
    model, _, args = setup
    cached, cached_logits = generation.generate(model, *args, max_new_tokens=NEW, use_cache=True, return_logits=True)
    plain, plain_logits = generation.generate(model, *args, max_new_tokens=NEW, use_cache=False, return_logits=True)
    np.testing.assert_array_equal(np.asarray(cached), np.asarray(plain))
    np.testing.assert_allclose(np.asarray(cached_logits), np.asarray(plain_logits), atol=1e-5)
    # and the last step's logits equal one forward pass over prompt + generated tokens
    ids, mask, image_mask, embeds = args
    full_ids = jnp.concatenate([ids, cached[:, :-1]], axis=1)
    full_mask = jnp.concatenate([mask, jnp.ones_like(cached[:, :-1], bool)], axis=1)
    full_image = jnp.concatenate([image_mask, jnp.zeros_like(cached[:, :-1], bool)], axis=1)
    logits = forward(model, full_ids, full_mask, full_image, image_embeds=embeds)
    np.testing.assert_allclose(np.asarray(logits[:, ids.shape[1] - 1:]), np.asarray(cached_logits), atol=1e-5)


class EosFirstOnRowZero(generation.NoConstraint):
    """Row 0 must end at once; the other rows may not end."""

    def __init__(self, eos_id):
        self.eos_id = eos_id

    def allowed(self, state, vocab_size, remaining):
        eos = jnp.arange(vocab_size) == self.eos_id
        return jnp.where((jnp.arange(state.shape[0]) == 0)[:, None], eos, ~eos)


def test_cached_and_uncached_decoding_agree_after_an_eos(setup):
    """Padding after a row's EOS is masked the same way with and without the cache."""
    model, _, args = setup
    constraint = EosFirstOnRowZero(model.config.text.eos_token_id)
    cached, cached_logits = generation.generate(model, *args, max_new_tokens=NEW, constraint=constraint, return_logits=True)
    plain, plain_logits = generation.generate(model, *args, max_new_tokens=NEW, constraint=constraint, use_cache=False,
                                          return_logits=True)
    assert cached[0, 0] == model.config.text.eos_token_id and (cached[0, 1:] == model.config.text.pad_token_id).all()
    np.testing.assert_array_equal(np.asarray(cached), np.asarray(plain))
    np.testing.assert_allclose(np.asarray(cached_logits), np.asarray(plain_logits), atol=1e-5)
    # row 0's logits two steps after its EOS: prompt + EOS seen, the padding token at the padding position
    ids, mask, image_mask, embeds = (a[:1] for a in args)
    cfg = model.config.text
    tail = jnp.asarray([[cfg.eos_token_id, cfg.pad_token_id]], ids.dtype)
    alone = forward(model, jnp.concatenate([ids, tail], 1), jnp.concatenate([mask, jnp.asarray([[True, False]])], 1),
                    jnp.concatenate([image_mask, jnp.zeros((1, 2), bool)], 1), image_embeds=embeds)
    np.testing.assert_allclose(np.asarray(cached_logits[0, 2]), np.asarray(alone[0, -1]), atol=1e-5)


def test_too_few_new_tokens_for_the_constraint_are_refused(setup):
    model, _, args = setup

    class LongAnswers(generation.NoConstraint):
        min_tokens = NEW + 1

    with pytest.raises(ValueError, match=f"max_new_tokens={NEW} is too few.*{NEW + 1} tokens"):
        generation.generate(model, *args, max_new_tokens=NEW, constraint=LongAnswers())


def test_greedy_tokens_match_transformers_generate(setup):
    model, ref, args = setup
    tokens = generation.generate(model, *args, max_new_tokens=NEW)
    # the fixture's greedy ids are for the unpadded rows (transformers shifts padded rows' positions)
    np.testing.assert_array_equal(np.asarray(tokens[:-1]), ref["greedy_ids"])


def test_left_padding_changes_nothing(setup):
    model, ref, args = setup
    ids, mask, image_mask, embeds = args
    batched, batched_logits = generation.generate(model, *args, max_new_tokens=NEW, return_logits=True)
    pad = int((~mask[-1]).sum())
    alone, alone_logits = generation.generate(model, ids[-1:, pad:], mask[-1:, pad:], image_mask[-1:, pad:], embeds[-1:],
                                          max_new_tokens=NEW, return_logits=True)
    np.testing.assert_array_equal(np.asarray(batched[-1:]), np.asarray(alone))
    np.testing.assert_allclose(np.asarray(batched_logits[-1:]), np.asarray(alone_logits), atol=1e-5)


def test_rows_stop_at_eos_and_then_emit_padding(setup):
    model, _, args = setup
    cfg = model.config.text

    class ForceEos(generation.NoConstraint):
        def allowed(self, state, vocab_size, remaining):
            return jnp.zeros((state.shape[0], vocab_size), bool).at[:, cfg.eos_token_id].set(True)

    tokens = np.asarray(generation.generate(model, *args, max_new_tokens=3, constraint=ForceEos()))
    assert (tokens[:, 0] == cfg.eos_token_id).all() and (tokens[:, 1:] == cfg.pad_token_id).all()
