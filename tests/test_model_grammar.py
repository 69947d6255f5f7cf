"""Constrained decoding: the grammar admits every formatted answer, and every constrained answer parses."""

import functools
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax import grasp_text
from kosmos_jax.models import decode, weights
from kosmos_jax.models.grammar import TokenConstraint

FIXTURE = pathlib.Path(__file__).parent / "fixtures" / "kosmos2_tiny"
SPECIALS = ["<s>", "<pad>", "</s>", "<unk>"]
EOS = 2
WORDS = ["Grasp", " Grasp", " center", " point", " coordinates", ":", " x", "x_", "_", ",y_", ",", " rotation",
         " angle", " in", " radians", " a_", " bounding", " box", " width", " and", " height", " w_", ",h_",
         ",x_", "12", "22", "255", "100", "0", "00", "-1.", "57", ".5", "1,y_2",
         "3,y_4,", "<patch_index_", "> Grasp", "hello", " the", "999", "..", "--", "Grasp center"]


def toy_vocabulary(patch_tokens: bool = True):
    chars = sorted(set("".join(grasp_text.REPRESENTATIONS)) | set("Grasp center point coordinates: x_,y_ rotation"
                                                                     " angle in radians: a_ width and height w_ h_ "
                                                                     "bounding box <patch_index_> -.0123456789"))
    vocab = SPECIALS + chars + WORDS
    if patch_tokens:
        vocab += [f"<patch_index_{i:04d}>" for i in range(1024)]
    return vocab


def tokenize(text, vocab):
    """Greedy longest match (any segmentation works for the grammar)."""
    pieces = sorted(((t, i) for i, t in enumerate(vocab) if i >= len(SPECIALS)), key=lambda p: -len(p[0]))
    ids, pos = [], 0
    while pos < len(text):
        token, i = next((t, i) for t, i in pieces if text.startswith(t, pos))
        ids.append(i)
        pos += len(token)
    return ids


@functools.partial(jax.jit, static_argnums=(0,))
def constrained_walk(constraint, logits):
    """Greedy choice under the constraint for fixed random logits [steps, B, V]."""
    def body(carry, step_logits):
        cstate, done = carry
        allowed = constraint.allowed(cstate, step_logits.shape[-1])
        token = jnp.argmax(jnp.where(allowed, step_logits, -jnp.inf), axis=-1)
        token = jnp.where(done, 1, token)
        cstate = constraint.advance(cstate, token)
        return (cstate, done | (token == EOS)), token

    _, tokens = jax.lax.scan(body, (constraint.init(logits.shape[1]), jnp.zeros(logits.shape[1], bool)), logits)
    return tokens.T


def detokenize(ids, vocab):
    ids = list(ids)
    assert EOS in ids, "the answer never ended"
    return "".join(vocab[i] for i in ids[:ids.index(EOS)])


CASES = [("xya", True), ("xya", False), ("xywha", True), ("tlbra", True), ("tlbra_patch", True)]


@pytest.mark.parametrize("representation,angle_code", CASES)
def test_random_logits_under_the_constraint_always_give_a_parsable_answer(representation, angle_code):
    vocab = toy_vocabulary()
    constraint = TokenConstraint(vocab, EOS, representation, angle_code=angle_code, image_size=224)
    logits = jax.random.normal(jax.random.key(0), (140, 64, len(vocab)))
    tokens = np.asarray(constrained_walk(constraint, logits))
    for row in tokens:
        text = detokenize(row, vocab)
        parsed = grasp_text.parse_grasp(text, representation, angle_code=angle_code, image_size=224)
        assert parsed.ok, (text, parsed.error)


@pytest.mark.parametrize("representation,angle_code", CASES)
def test_every_formatted_answer_is_admitted(representation, angle_code):
    vocab = toy_vocabulary()
    constraint = TokenConstraint(vocab, EOS, representation, angle_code=angle_code, image_size=224)
    step = jax.jit(lambda cstate, token: (constraint.allowed(cstate, len(vocab))[0], constraint.advance(cstate, token)))
    rng = np.random.default_rng(1)
    for _ in range(15):
        grasp = [rng.uniform(40, 180), rng.uniform(40, 180), rng.uniform(10, 60), rng.uniform(5, 30), rng.uniform(-1.5, 1.5)]
        text = " " + grasp_text.format_grasp(grasp, representation, angle_code=angle_code, image_size=224)
        cstate = constraint.init(1)
        for token in tokenize(text, vocab):
            allowed, cstate = step(cstate, jnp.asarray([token]))
            assert bool(allowed[token]), (text, vocab[token])
        allowed, _ = step(cstate, jnp.asarray([EOS]))
        assert bool(allowed[EOS]), text


def test_order_relations_are_enforced():
    vocab = toy_vocabulary()
    constraint = TokenConstraint(vocab, EOS, "tlbra")
    cstate = constraint.init(1)
    for token in tokenize("Grasp bounding box: x_150,y_30,x_", vocab):
        cstate = constraint.advance(cstate, jnp.asarray([token]))
    allowed = np.asarray(constraint.allowed(cstate, len(vocab))[0])
    assert allowed[vocab.index("2")] and not allowed[vocab.index("0")]  # 2xx can reach >= 150; "0" cannot
    assert allowed[vocab.index("1")]  # 15x.. still possible
    assert not allowed[vocab.index("12")]  # 12 and 12x are < 150 or > 223
    patch = TokenConstraint(vocab, EOS, "tlbra_patch")
    cstate = patch.init(1)
    for token in tokenize("Grasp bounding box: <patch_index_0100>", vocab):  # row 3, column 4
        cstate = patch.advance(cstate, jnp.asarray([token]))
    allowed = np.asarray(patch.allowed(cstate, len(vocab))[0])
    assert allowed[vocab.index("<patch_index_0101>")] and allowed[vocab.index("<patch_index_0132>")]
    assert not allowed[vocab.index("<patch_index_0099>")]  # column 3 < 4
    assert not allowed[vocab.index("<patch_index_0068>")]  # row 2 < 3


def test_constrained_generation_with_the_model_parses():
    model = weights.load_pretrained(FIXTURE)
    model.eval()
    ref = dict(np.load(FIXTURE / "reference.npz"))
    chars = sorted(set("Grasp center point coordinates: x_,y_ rotation angle in radians: a_0123456789"))
    vocab = SPECIALS + chars + WORDS
    vocab = (vocab + [f"junk{i}" for i in range(99)])[:99]
    constraint = TokenConstraint(vocab, EOS, "xya", image_size=224)
    args = (jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool),
            jnp.asarray(ref["image_embeds_position_mask"], bool), jnp.asarray(ref["image_embeds"]))
    tokens = np.asarray(decode.generate(model, *args, max_new_tokens=100, constraint=constraint))
    free = np.asarray(decode.generate(model, *args, max_new_tokens=10))
    assert not all(grasp_text.parse_grasp("".join(vocab[i] for i in row)).ok for row in free)
    for row in tokens:
        assert grasp_text.parse_grasp(detokenize(row, vocab), "xya").ok


def test_a_vocabulary_that_cannot_spell_an_answer_is_refused():
    with pytest.raises(ValueError, match="no token"):
        TokenConstraint(SPECIALS + ["hello", "world"], EOS, "xya")
