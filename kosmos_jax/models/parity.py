"""The PyTorch reference: a tiny random Kosmos2ForConditionalGeneration of transformers (extra `parity`).

Only this module imports torch/transformers, and only when called. `make_reference` builds the
model at transformers' own test sizes (tests/models/kosmos2/test_modeling_kosmos2.py), perturbs
every parameter (so LayerNorm scales and biases are not the trivial 1 and 0 and a wrong mapping
shows), saves it in the transformers layout and returns inputs and outputs as numpy arrays.
"""

from __future__ import annotations

import pathlib

import numpy as np

TINY_TEXT = dict(vocab_size=99, embed_dim=32, layers=2, attention_heads=4, ffn_dim=37, dropout=0.1,
                 attention_dropout=0.1, max_position_embeddings=512)
TINY_VISION = dict(image_size=32, patch_size=4, num_channels=3, hidden_size=32, num_hidden_layers=2,
                   num_attention_heads=4, intermediate_size=37, dropout=0.1, attention_dropout=0.1)
LATENTS = 3
PAD, BOS = 1, 0


def reference_inputs(seed: int, batch: int = 3, length: int = 12) -> dict[str, np.ndarray]:
    """`<s>` + 3 image slots + text; the last row left-padded by 3 (pad id 1, attention 0)."""
    rng = np.random.default_rng(seed)
    ids = rng.integers(4, TINY_TEXT["vocab_size"], (batch, length))
    attention = np.ones((batch, length), np.int64)
    image_mask = np.zeros((batch, length), np.int64)
    for row in range(batch):
        pad = 3 if row == batch - 1 else 0
        ids[row, :pad], attention[row, :pad] = PAD, 0
        ids[row, pad] = BOS
        image_mask[row, pad + 1: pad + 1 + LATENTS] = 1
    pixels = rng.normal(size=(batch, 3, TINY_VISION["image_size"], TINY_VISION["image_size"])).astype(np.float32)
    return {"input_ids": ids, "attention_mask": attention, "image_embeds_position_mask": image_mask,
            "pixel_values": pixels}


def make_reference(folder: str | pathlib.Path, seed: int = 0, new_tokens: int = 4) -> dict[str, np.ndarray]:
    """Save a random tiny KOSMOS-2 to `folder`; return its inputs, image embeds, logits and greedy ids."""
    import torch
    from transformers import Kosmos2Config, Kosmos2ForConditionalGeneration

    torch.manual_seed(seed)
    config = Kosmos2Config(text_config=TINY_TEXT, vision_config=TINY_VISION, latent_query_num=LATENTS)
    model = Kosmos2ForConditionalGeneration(config).eval()
    with torch.no_grad():
        for name, param in model.named_parameters():
            param.add_(torch.randn_like(param) * (0.1 if param.ndim == 1 else 0.02))
    model.save_pretrained(str(folder))
    arrays = reference_inputs(seed)
    inputs = {k: torch.from_numpy(v) for k, v in arrays.items()}
    with torch.no_grad():
        out = model(**inputs)
        unpadded = {k: v[:-1] for k, v in inputs.items()}  # HF shifts positions of left-padded rows in generate
        generated = model.generate(**unpadded, max_new_tokens=new_tokens, do_sample=False, num_beams=1,
                                   min_new_tokens=new_tokens, use_cache=True)
    arrays.update(image_embeds=out.image_embeds.numpy(), logits=out.logits.numpy(),
                  greedy_ids=generated[:, -new_tokens:].numpy())
    return arrays
