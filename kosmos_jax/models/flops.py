"""The model's own FLOPs of one train step: a function of the config, not of the compiled program.

Counted: every matmul (2 FLOPs a multiply-add) of the vision tower, the connector, the decoder and
the tied LM head, and attention's two products (scores and the weighted sum, over every key: the
masked ones are computed too). Not counted: elementwise work (LayerNorm, softmax, GELU, dropout),
the image's resize and the optimiser. The backward pass is twice the forward (the gradients of a
matmul's input and of its weight), except for the patch embedding, whose input is the image: it
gets no gradient. XLA's cost analysis counts a loop's body once; this count does not see loops, so
`scan_layers` and microbatches leave it as it is. `xla_flops` is XLA's count of a compiled program,
to set beside it.
"""

from __future__ import annotations

import dataclasses

import jax

from kosmos_jax.models.config import Kosmos2Config


@dataclasses.dataclass(frozen=True)
class TrainFlops:
    """FLOPs of one train step over the whole batch, forward parts by name."""

    patch_embedding: int
    vision_matmuls: int  # q, k, v, out projections and the MLP of every block
    vision_attention: int
    connector_matmuls: int  # the dense layer and the latent queries' attention projections
    connector_attention: int
    decoder_matmuls: int
    decoder_attention: int
    lm_head: int
    remat_forward: int  # under remat, the blocks' forward again in the backward pass; 0 without

    @property
    def forward(self) -> int:
        return sum(self.parts().values())

    @property
    def backward(self) -> int:
        return 2 * self.forward - self.patch_embedding  # no gradient for the image

    @property
    def model(self) -> int:
        """Forward and backward: the FLOPs MFU is measured by (remat's recomputation left out)."""
        return self.forward + self.backward

    @property
    def executed(self) -> int:
        """What the step runs, remat's recomputation included."""
        return self.model + self.remat_forward

    def parts(self) -> dict[str, int]:
        """The forward's parts by name."""
        return {field.name: getattr(self, field.name) for field in dataclasses.fields(self)
                if field.name != "remat_forward"}

    def as_dict(self) -> dict[str, int]:
        return {**self.parts(), "forward": self.forward, "backward": self.backward,
                "remat_forward": self.remat_forward, "model": self.model, "executed": self.executed}


def attention_flops(queries: int, keys: int, width: int) -> int:
    """Scores (queries x keys x width) and the weighted sum of values (the same), for all heads."""
    return 2 * 2 * queries * keys * width


def train_flops(cfg: Kosmos2Config, batch_size: int, length: int) -> TrainFlops:
    """FLOPs of one train step of `batch_size` sequences of `length` tokens, each with one image."""
    vision, text = cfg.vision, cfg.text
    tokens, width = vision.num_positions, vision.hidden_size
    vision_block = 2 * tokens * (4 * width * width + 2 * width * vision.intermediate_size)
    vision_attention = attention_flops(tokens, tokens, width)

    queries, d = cfg.latent_query_num, text.embed_dim
    keys = tokens + queries  # the projected image tokens and the queries themselves
    connector = 2 * tokens * width * d + 2 * d * d * (2 * queries + 2 * keys)  # dense; q and out; k and v

    decoder_block = 2 * length * (4 * d * d + 2 * d * text.ffn_dim)
    decoder_attention = attention_flops(length, length, d)
    # Remat recomputes a block's forward for its backward, less the block's last matmul (fc2): the
    # backward needs that matmul's input, not its output, so jax leaves it out of the recomputation.
    vision_fc2, decoder_fc2 = 2 * tokens * vision.intermediate_size * width, 2 * length * text.ffn_dim * d
    # Under the "dots" policy the dense layers' outputs are kept: only attention's products run again.
    if cfg.remat_policy == "dots":
        recomputed = vision.num_hidden_layers * vision_attention + text.layers * decoder_attention
    else:
        recomputed = (vision.num_hidden_layers * (vision_block + vision_attention - vision_fc2)
                      + text.layers * (decoder_block + decoder_attention - decoder_fc2))
    return TrainFlops(
        patch_embedding=batch_size * 2 * vision.num_patches * vision.num_channels * vision.patch_size**2 * width,
        vision_matmuls=batch_size * vision.num_hidden_layers * vision_block,
        vision_attention=batch_size * vision.num_hidden_layers * vision_attention,
        connector_matmuls=batch_size * connector,
        connector_attention=batch_size * attention_flops(queries, keys, d),
        decoder_matmuls=batch_size * text.layers * decoder_block,
        decoder_attention=batch_size * text.layers * decoder_attention,
        lm_head=batch_size * 2 * length * d * text.vocab_size,
        remat_forward=batch_size * recomputed if cfg.remat else 0,
    )


def xla_flops(compiled) -> float | None:
    """XLA's FLOPs of one device's compiled program, or None where the backend's cost analysis gives
    none (a TPU topology's lowered program, with jax 0.10.2). XLA counts a loop's body once, so with
    scan_layers or microbatches it falls short of the model's count."""
    try:
        analysis = compiled.cost_analysis()
    except (NotImplementedError, jax.errors.JaxRuntimeError):
        return None
    if isinstance(analysis, (list, tuple)):  # one dict a program in older jax versions
        analysis = analysis[0] if len(analysis) == 1 else None
    if not isinstance(analysis, dict) or analysis.get("flops") is None:
        return None
    return float(analysis["flops"])
