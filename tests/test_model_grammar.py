"""Constrained decoding: the grammar admits every formatted answer, and every constrained answer parses."""

import functools
import pathlib
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax import grasp_text
from kosmos_jax.models import generation, grammar_budget, weights
from kosmos_jax.models.grammar import TokenConstraint, answer_template, cue_constraints
from kosmos_jax.text import formatter

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
def constrained_walk(constraint, logits, budget=None):
    """Greedy choice under the constraint for fixed logits [steps, B, V], `budget` (default: steps)
    tokens at most."""
    steps = logits.shape[0]
    budget = steps if budget is None else budget

    def body(carry, xs):
        cstate, done = carry
        step_logits, i = xs
        allowed = constraint.allowed(cstate, step_logits.shape[-1], budget - i)
        token = jnp.argmax(jnp.where(allowed, step_logits, -jnp.inf), axis=-1)
        token = jnp.where(done, 1, token)
        cstate = constraint.advance(cstate, token)
        return (cstate, done | (token == EOS)), token

    init = (constraint.init(logits.shape[1]), jnp.zeros(logits.shape[1], bool))
    _, tokens = jax.lax.scan(body, init, (logits, jnp.arange(steps)))
    return tokens.T


def detokenize(ids, vocab):
    ids = list(ids)
    assert EOS in ids, "the answer never ended"
    return "".join(vocab[i] for i in ids[:ids.index(EOS)])


CASES = [(r, code) for r in grasp_text.REPRESENTATIONS for code in (True, False)]


@pytest.fixture(scope="module")
def toy_constraints():
    vocab = toy_vocabulary()
    return vocab, {case: TokenConstraint(vocab, EOS, case[0], angle_code=case[1]) for case in CASES}


@pytest.fixture(scope="module")
def toy_part_constraints():
    """Location values of the representations with order relations, on their last field too."""
    vocab = toy_vocabulary()
    return vocab, {r: TokenConstraint(vocab, EOS, r, part="location") for r in ("tlbra", "tlbra_patch")}


@pytest.mark.parametrize("representation,angle_code", CASES)
def test_random_logits_under_the_constraint_always_give_a_parsable_answer(toy_constraints, representation, angle_code):
    vocab, constraints = toy_constraints
    constraint = constraints[representation, angle_code]
    # a generous budget, then exactly the shortest answer's length: every row must still finish
    logits = jax.random.normal(jax.random.key(0), (3 * constraint.min_tokens, 64, len(vocab)))
    for budget in (3 * constraint.min_tokens, constraint.min_tokens):
        for row in np.asarray(constrained_walk(constraint, logits, budget)):
            text = detokenize(row[:budget], vocab)
            parsed = grasp_text.parse_grasp(text, representation, angle_code=angle_code, image_size=224)
            assert parsed.ok, (text, parsed.error)


def random_grasps(n: int, representation: str, size: int, seed: int) -> np.ndarray:
    """Grasps whose text format_grasp writes and parse_grasp accepts (centres in the image, w and h
    at least a pixel): centres near the edges, boxes beyond the image, tiny and huge w, h, all angles."""
    rng = np.random.default_rng(seed)
    edges = np.array([0.0, 0.3, 0.5, size / 2, size - 1.5, size - 1.0])
    centres = np.where(rng.random((n, 2)) < 0.4, rng.choice(edges, (n, 2)), rng.uniform(0, size - 1, (n, 2)))
    # TLBRA's box must stay within [-S, 2S] around any centre: half its diagonal below S
    largest = 1.4 * size if representation == "tlbra" else 2 * size
    sizes = np.where(rng.random((n, 2)) < 0.3, rng.uniform(1, 2, (n, 2)), rng.uniform(1, largest, (n, 2)))
    angles = rng.uniform(-np.pi / 2, np.pi / 2, n)
    angles[:6] = [-np.pi / 2, np.pi / 2 - 1e-4, 0.0, -1e-4, np.pi / 4, np.pi / 2 - np.pi / 512]
    return np.column_stack([centres, sizes, angles])


def character_vocabulary():
    chars = sorted(set("".join(grasp_text.format_grasp([1, 2, 3, 4, 0.5], r, c) for r, c in CASES))
                   | set("-.0123456789<>_ "))
    return SPECIALS + chars


PART_CASES = [(r, code, part) for r in grasp_text.REPRESENTATIONS for code in (True, False)
              for part in formatter.PARTS]


@pytest.mark.parametrize("representation,angle_code,part", PART_CASES)
def test_every_formatted_value_is_admitted_char_by_char_and_parses(representation, angle_code, part):
    """The values formatter writes for `part` (the whole answer in joint mode, the value after the
    cue in individual mode), each spelled as layout's tokens spell its segment: a leading space,
    or none (both are admitted), then EOS."""
    config = formatter.FormatConfig(representation, angle_code, individual=part != "grasp", image_size=224)
    vocab = character_vocabulary()
    constraint = TokenConstraint.for_part(vocab, EOS, config, part)
    grasps = random_grasps(300, representation, config.image_size, seed=len(representation) + angle_code)
    examples = [next((cue, value) for p, cue, value, _ in formatter.grasp_parts(g, "grasp", config) if p == part)
                for g in grasps]
    for cue, value in examples:
        text = formatter.target_text(cue, value)
        parsed = formatter.parse_target(text, part, config)
        assert parsed.ok, (text, parsed.error)
    values = [value for _, value in examples]
    if representation == "tlbra" and part != "angle":  # the box does stick out of the image
        boxes = np.array([[int(v) for v in re.findall(r"-?\d+", t.split("a_")[0])] for t in values])
        assert boxes.min() < -20 and boxes.max() > config.image_size + 20
    texts = [" " * (row % 2 == 0) + value for row, value in enumerate(values)]
    admitted = np.asarray(admission(constraint, spelled(texts, vocab)))
    for row, text in enumerate(texts):
        assert admitted[row, :len(text) + 1].all(), (text, text[:int(np.argmin(admitted[row]))])


def spelled(texts, vocab, length=None):
    """[N, L] ids of the texts character by character, then EOS, then -1 (nothing)."""
    index = {ch: i for i, ch in enumerate(vocab)}
    ids = np.full((len(texts), length or max(map(len, texts)) + 1), -1, np.int32)
    for row, text in enumerate(texts):
        ids[row, :len(text) + 1] = [index[ch] for ch in text] + [EOS]
    return jnp.asarray(ids)


def test_a_part_admits_its_value_only():
    vocab = character_vocabulary()
    location = TokenConstraint(vocab, EOS, "xya", part="location")
    angle = TokenConstraint(vocab, EOS, "xya", part="angle")
    ok = lambda constraint, text: bool(np.asarray(admission(constraint, spelled([text], vocab, 48))).all())  # noqa: E731
    assert ok(location, " x_12,y_3") and ok(angle, " a_77")
    assert not ok(location, " Grasp center point coordinates: x_12,y_3")  # the cue is the prompt's
    assert not ok(location, "  x_12,y_3")  # one leading space at most
    assert not ok(location, " x_12,y_3 ")  # EOS right after the value
    assert not ok(location, " x_224,y_3") and not ok(angle, " a_256")
    assert not ok(location, " a_77") and not ok(angle, " x_12,y_3")


def test_an_unknown_part_is_refused():
    with pytest.raises(ValueError, match=r"unknown part 'centre'; expected one of \('grasp', 'location'"):
        TokenConstraint(character_vocabulary(), EOS, "xya", part="centre")
    with pytest.raises(ValueError, match="unknown part 'value'"):
        TokenConstraint.for_part(character_vocabulary(), EOS, formatter.FormatConfig(), "value")
    with pytest.raises(ValueError, match="unknown part 'Location'"):
        answer_template("xya", "Location")


@functools.partial(jax.jit, static_argnums=(0,))
def admission(constraint, ids):
    """[N, L] bool: was each token of the rows (-1 = none) allowed with a budget of L tokens?"""
    def body(cstate, xs):
        token, i = xs
        allowed = constraint.allowed(cstate, constraint.vocab_size, ids.shape[1] - i)
        ok = jnp.take_along_axis(allowed, jnp.maximum(token, 0)[:, None], axis=1)[:, 0] | (token < 0)
        return constraint.advance(cstate, jnp.where(token < 0, 1, token)), ok

    _, ok = jax.lax.scan(body, constraint.init(ids.shape[0]), (ids.T, jnp.arange(ids.shape[1])))
    return ok.T


def allowed_after(constraint, prefix, vocab):
    """The tokens allowed after `prefix` (padded with -1 to a fixed length: one compilation)."""
    ids = np.full((1, 40), -1, np.int32)
    tokens = tokenize(prefix, vocab)
    ids[0, :len(tokens)] = tokens
    return np.asarray(_allowed_after(constraint, jnp.asarray(ids)))[0]


@functools.partial(jax.jit, static_argnums=(0,))
def _allowed_after(constraint, ids):
    def body(cstate, token):
        return constraint.advance(cstate, jnp.where(token < 0, 1, token)), None  # the pad id leaves the state

    cstate, _ = jax.lax.scan(body, constraint.init(ids.shape[0]), ids.T)
    return constraint.allowed(cstate, constraint.vocab_size, 100)


def test_cue_constraints_follow_the_format_config():
    vocab = ["<s>", "<pad>", "</s>", "<unk>", *sorted(set("Grasp center point coordinates: x_,y_ rotation angle in "
                                                          "radians: a_ bounding box -.0123456789<>"))]
    spell = lambda text: [vocab.index(ch) for ch in text] + [2, 1]  # noqa: E731  EOS, then padding

    individual = formatter.FormatConfig("tlbra", angle_code=False)
    prompts = cue_constraints(vocab, 2, individual)
    assert [(p.part, p.cue) for p in prompts] == [("location", "Grasp bounding box:"),
                                                  ("angle", "Grasp rotation angle in radians:")]
    assert [p.constraint.part for p in prompts] == ["location", "angle"]
    assert all(not p.constraint.angle_code and p.constraint.representation == "tlbra" for p in prompts)
    location, angle = prompts
    assert location.target_text(spell(" x_-3,y_4,x_9,y_8")) == "Grasp bounding box: x_-3,y_4,x_9,y_8"
    assert angle.target_text(spell("a_-0.52")) == "Grasp rotation angle in radians: a_-0.52"

    centre = cue_constraints(vocab, 2, formatter.FormatConfig("xya"), answer="centre")
    assert [(p.part, p.cue, p.constraint.part) for p in centre] == [
        ("location", "Grasp center point coordinates:", "location")]
    joint = cue_constraints(vocab, 2, formatter.FormatConfig("xya", individual=False))
    assert [(p.part, p.cue, p.constraint.part) for p in joint] == [("grasp", "", "grasp")]
    answer = "Grasp center point coordinates: x_1,y_2 Grasp rotation angle in radians: a_3"
    assert joint[0].target_text(spell(" " + answer)) == answer


def test_a_centre_answer_in_joint_mode_writes_its_cue():
    """Joint mode puts no cue in the prompt, so a centre answer is the whole location text."""
    vocab = character_vocabulary()
    config = formatter.FormatConfig("xya", individual=False)
    (prompt,) = cue_constraints(vocab, EOS, config, answer="centre")
    assert (prompt.part, prompt.cue) == ("location", "")
    admitted = lambda text: bool(np.asarray(admission(prompt.constraint, spelled([text], vocab, 48))).all())  # noqa: E731
    answer = "Grasp center point coordinates: x_1,y_2"
    assert admitted(" " + answer) and not admitted(" x_1,y_2")
    assert formatter.parse_target(prompt.target_text(spelled([" " + answer], vocab)[0]), "location", config).ok


def test_order_relations_are_enforced(toy_constraints):
    vocab, constraints = toy_constraints
    box = constraints["tlbra", True]
    allowed = allowed_after(box, "Grasp bounding box: x_150,y_30,x_", vocab)  # x2 in [150, 297]
    assert allowed[vocab.index("2")] and allowed[vocab.index("1")]  # 2xx, 15x..19x
    assert not allowed[vocab.index("0")] and not allowed[vocab.index("12")]  # 0, 12, 12x < 150
    assert not allowed[vocab.index("3")]  # 3, 3x < 150 and 3xx puts the middle past the image
    allowed = allowed_after(box, "Grasp bounding box: x_3", vocab)  # x1 = 300 leaves no x2
    assert allowed[vocab.index("0")] and not allowed[vocab.index("00")]
    allowed = allowed_after(box, "Grasp bounding box: x_-19,y_", vocab)  # negative corners are fine
    assert allowed[vocab.index("22")] and allowed[vocab.index("-")]
    patch = constraints["tlbra_patch", True]
    allowed = allowed_after(patch, "Grasp bounding box: <patch_index_0100>", vocab)  # row 3, column 4
    assert allowed[vocab.index("<patch_index_0101>")] and allowed[vocab.index("<patch_index_0132>")]
    assert not allowed[vocab.index("<patch_index_0099>")]  # column 3 < 4
    assert not allowed[vocab.index("<patch_index_0068>")]  # row 2 < 3


def test_order_relations_hold_up_to_a_values_last_field(toy_part_constraints):
    """In a location value the relation's upper field is the last one: EOS completes it."""
    vocab, constraints = toy_part_constraints
    eos = lambda allowed: bool(allowed[EOS])  # noqa: E731
    box = constraints["tlbra"]
    assert not eos(allowed_after(box, " x_150,y_30,x_200,y_3", vocab))  # y2 = 3 < y1
    assert allowed_after(box, " x_150,y_30,x_200,y_3", vocab)[vocab.index("0")]
    assert eos(allowed_after(box, " x_150,y_30,x_200,y_30", vocab))
    allowed = allowed_after(box, " x_150,y_30,x_29", vocab)  # x2's middle with x1 inside: x2 <= 297
    assert allowed[vocab.index("7")] and not allowed[vocab.index("8")] and not eos(allowed)
    patch = constraints["tlbra_patch"]
    allowed = allowed_after(patch, " <patch_index_0100>", vocab)
    assert allowed[vocab.index("<patch_index_0101>")] and not allowed[vocab.index("<patch_index_0099>")]
    assert not eos(allowed)
    assert eos(allowed_after(patch, " <patch_index_0100><patch_index_0132>", vocab))


@pytest.mark.parametrize("representation", ["tlbra", "tlbra_patch"])
def test_random_logits_give_parsable_location_values(toy_part_constraints, representation):
    vocab, constraints = toy_part_constraints
    constraint = constraints[representation]
    config = formatter.FormatConfig(representation)
    cue = dict(formatter.prompt_cues(config))["location"]
    logits = jax.random.normal(jax.random.key(1), (3 * constraint.min_tokens, 64, len(vocab)))
    values = set()
    for budget in (3 * constraint.min_tokens, constraint.min_tokens):
        for row in np.asarray(constrained_walk(constraint, logits, budget)):
            value = detokenize(row[:budget], vocab).removeprefix(" ")
            parsed = formatter.parse_target(formatter.target_text(cue, value), "location", config)
            assert parsed.ok, (value, parsed.error)
            values.add(value)
    assert len(values) > 10


def test_no_token_leads_into_a_state_with_no_way_out():
    answer = " " + grasp_text.format_grasp([100, 50, 30, 20, 0.3])
    vocab = SPECIALS + [" Grasp c", answer]
    constraint = TokenConstraint(vocab, EOS, "xya")
    assert constraint.min_tokens == 2
    logits = jnp.zeros((5, 1, len(vocab))).at[:, :, 4].set(10.0)  # the model prefers the dead end
    row = np.asarray(constrained_walk(constraint, logits))[0]
    assert detokenize(row, vocab) == answer


def test_the_shortest_answer_is_counted_exactly(toy_constraints):
    vocab, constraints = toy_constraints
    angle = [" Grasp", " rotation", " angle", " in", " radians", ":", " a_", "57"]
    shortest = {  # found by hand; EOS comes on top
        "xya": ["Grasp center", " point", " coordinates", ":", " x", "_", "1,y_2", *angle],
        "tlbra_patch": [" Grasp", " bounding", " box", ":", " ", "<patch_index_0012>", "<patch_index_1023>", *angle],
    }
    for representation, words in shortest.items():
        assert constraints[representation, True].min_tokens == len(words) + 1
        assert grasp_text.parse_grasp("".join(words), representation).ok


def test_a_vocabulary_that_cannot_spell_an_answer_is_refused():
    with pytest.raises(ValueError, match=r"no sequence of the vocabulary's tokens spells a whole xya grasp answer "
                                         r"\(angle_code=True, image_size=224\)"):
        TokenConstraint(SPECIALS + ["hello", "world"], EOS, "xya")
    with pytest.raises(ValueError, match="whole tlbra location answer"):  # no token at all: relations too
        TokenConstraint(SPECIALS + ["hello", "world"], EOS, "tlbra", part="location")
    # every piece of the answer is there but the angle's digits: refused at construction, by name
    vocab = [t for t in toy_vocabulary() if not re.fullmatch(r"[-.\d]+", t) or t in ("1,y_2",)]
    with pytest.raises(ValueError, match="whole xya grasp answer"):
        TokenConstraint(vocab, EOS, "xya")
    with pytest.raises(ValueError, match="whole xya angle answer"):  # the angle part alone as well
        TokenConstraint(vocab, EOS, "xya", part="angle")


def test_step_tables_are_int16_when_they_fit_and_int32_otherwise():
    for states in (100, 40_000):  # 40000 states do not fit int16
        base = np.arange(states, dtype=np.int32)
        tables = grammar_budget.Tables(base, np.zeros(states, np.int32), (), (), (), ())
        trans = np.array([[0, states - 1], [1, 2]], np.int32)
        field, value = np.array([[-1, 0], [1, -1]], np.int32), np.array([[-1, 5], [7, -1]], np.int32)
        table = grammar_budget.step_tables(tables, trans, field, value).table
        assert table.dtype == (np.int16 if states < 2 ** 15 else np.int32)
        np.testing.assert_array_equal(table, np.stack([trans, field, value, base[trans]], axis=-1))


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
    free = np.asarray(generation.generate(model, *args, max_new_tokens=10))
    assert not all(grasp_text.parse_grasp("".join(vocab[i] for i in row)).ok for row in free)
    for budget in (100, constraint.min_tokens):
        tokens = np.asarray(generation.generate(model, *args, max_new_tokens=budget, constraint=constraint))
        for row in tokens:
            assert grasp_text.parse_grasp(detokenize(row, vocab), "xya").ok
    with pytest.raises(ValueError, match=f"too few.*{constraint.min_tokens} tokens"):
        generation.generate(model, *args, max_new_tokens=constraint.min_tokens - 1, constraint=constraint)

