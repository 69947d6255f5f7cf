"""Parity with transformers' PyTorch Kosmos2ForConditionalGeneration.

The committed fixture (scripts/make_parity_fixture.py) holds a tiny random PyTorch model saved by
transformers plus its inputs and outputs; it is read here with our torch-free importer. The live
test rebuilds a fresh reference when torch and transformers are installed (extra `parity`).
"""

import importlib.util
import pathlib

import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

from kosmos_jax.models import weights
from kosmos_jax.models.kosmos2 import forward

FIXTURE = pathlib.Path(__file__).parent / "fixtures" / "kosmos2_tiny"
TOL = 1e-4


def our_outputs(folder, ref, **runtime):
    model = weights.load_pretrained(folder, **runtime)
    model.eval()
    pixels = jnp.asarray(ref["pixel_values"].transpose(0, 2, 3, 1))  # NCHW -> NHWC

    @nnx.jit
    def run(model, ids, attention, image_mask, pixels):
        embeds = model.image_embeds(pixels)
        return embeds, model(ids, attention, image_mask, image_embeds=embeds)

    return model, run(model, jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool),
                      jnp.asarray(ref["image_embeds_position_mask"], bool), pixels)


def assert_matches(ref, image_embeds, logits):
    assert np.max(np.abs(np.asarray(image_embeds) - ref["image_embeds"])) <= TOL
    real = ref["attention_mask"].astype(bool)  # padding rows' logits are meaningless in both
    diff = np.abs(np.asarray(logits) - ref["logits"])[real]
    assert diff.max() <= TOL, f"max abs logit difference {diff.max():.2e}"


def test_fixture_is_small_and_complete():
    names = {p.name for p in FIXTURE.iterdir()}
    assert {"config.json", "model.safetensors", "reference.npz"} <= names
    assert sum(p.stat().st_size for p in FIXTURE.iterdir()) < 512 * 1024


@pytest.mark.parametrize("scan_layers", [False, True])
def test_imported_fixture_matches_pytorch_image_embeds_and_logits(scan_layers):
    ref = dict(np.load(FIXTURE / "reference.npz"))
    _, (image_embeds, logits) = our_outputs(FIXTURE, ref, scan_layers=scan_layers)
    assert image_embeds.shape == ref["image_embeds"].shape == (3, 3, 32)
    assert ref["attention_mask"][-1, 0] == 0  # the fixture does exercise left padding
    assert_matches(ref, image_embeds, logits)


def test_a_wrong_mapping_would_be_caught():
    """The oracle is sharp: swapping two LayerNorm parameters moves the logits far past the tolerance."""
    ref = dict(np.load(FIXTURE / "reference.npz"))
    model = weights.load_pretrained(FIXTURE)
    model.eval()
    ln = model.text_model.model.layers[0].ffn.ffn_layernorm
    ln.scale.set_value(ln.scale.get_value()[::-1])
    logits = forward(model, jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool),
                   jnp.asarray(ref["image_embeds_position_mask"], bool), image_embeds=jnp.asarray(ref["image_embeds"]))
    real = ref["attention_mask"].astype(bool)
    assert np.abs(np.asarray(logits) - ref["logits"])[real].max() > 100 * TOL


needs_torch = pytest.mark.skipif(
    importlib.util.find_spec("torch") is None or importlib.util.find_spec("transformers") is None,
    reason="torch and transformers not installed (pip install -e '.[parity]')",
)


@needs_torch
def test_live_parity_with_a_fresh_pytorch_model(tmp_path):
    from kosmos_jax.models.parity import make_reference

    ref = make_reference(tmp_path / "hf", seed=7)
    model, (image_embeds, logits) = our_outputs(tmp_path / "hf", ref)
    assert_matches(ref, image_embeds, logits)
    # and back: our export loads in transformers and gives the same logits
    import torch
    from transformers import Kosmos2ForConditionalGeneration

    weights.save_pretrained(model, tmp_path / "ours")
    theirs = Kosmos2ForConditionalGeneration.from_pretrained(str(tmp_path / "ours")).eval()
    with torch.no_grad():
        out = theirs(**{k: torch.from_numpy(ref[k]) for k in
                        ("pixel_values", "input_ids", "attention_mask", "image_embeds_position_mask")})
    real = ref["attention_mask"].astype(bool)
    assert np.abs(out.logits.numpy() - ref["logits"])[real].max() <= TOL
