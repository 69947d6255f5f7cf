"""KOSMOS-2 (Kosmos2ForConditionalGeneration): vision tower -> connector -> MAGNETO decoder.

Parameter paths equal transformers' state-dict keys up to the leaf name (weight -> kernel / scale /
embedding), e.g. `text_model.model.layers.0.self_attn.inner_attn_ln.scale`.
"""

from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
from flax import nnx
from jax._src.interpreters import partial_eval  # private: see _cheap_tracer_errors

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.connector_extensions import instruction_bag, projection
from kosmos_jax.models.decoder import TextForCausalLM, position_ids
from kosmos_jax.models.vision import VisionModel


class Kosmos2(nnx.Module):
    def __init__(self, cfg: Kosmos2Config, rngs: nnx.Rngs):
        self.config = cfg
        layout = dict(scan_layers=cfg.scan_layers, remat=cfg.remat, remat_policy=cfg.remat_policy,
                      attention=cfg.attention)
        self.text_model = TextForCausalLM(cfg.text, cfg.dtype, rngs, cfg.magneto_gain, **layout)
        self.vision_model = VisionModel(cfg.vision, cfg.dtype, rngs, **layout)
        self.image_to_text_projection = projection(cfg, rngs)

    def image_embeds(self, pixels: jax.Array, instruction: jax.Array | None = None) -> jax.Array:
        """pixels [B, H, W, 3] -> [B, latent_query_num, D_text]; `instruction` the prompt's bag of words
        (`instruction_bag`), read by a connector with connector_instruction only."""
        return self.image_to_text_projection(self.vision_model(pixels), instruction)

    def instruction_bag(self, input_ids, attention_mask, image_mask, answer_mask=None) -> jax.Array | None:
        """What a connector with connector_instruction reads (connector_extensions.instruction_bag); None for the others."""
        if not self.config.connector_instruction:
            return None
        table = self.text_model.model.embed_tokens.embedding[...]
        return instruction_bag(table, input_ids, attention_mask, image_mask, answer_mask)

    def __call__(self, input_ids, attention_mask, image_mask, pixels=None, image_embeds=None):
        """Logits [B, T, V] (float32) for a whole sequence, no cache.

        input_ids/attention_mask/image_mask are [B, T]; image_mask marks the latent_query_num slots
        the image embeddings are written into. Give `pixels` or precomputed `image_embeds`.
        Positions come from attention_mask (transformers derives them from input_ids != pad id;
        the same when padding uses the pad id).
        """
        if image_embeds is None:
            if pixels is None:
                raise ValueError("give pixels or image_embeds")
            if self.config.connector_instruction:
                raise ValueError("a connector that reads the instruction needs to know where the answer starts: "
                                 "give image_embeds (image_embeds(pixels, instruction_bag(...)))")
            image_embeds = self.image_embeds(pixels)
        positions = position_ids(attention_mask, self.config.text.pad_token_id)
        hidden, _ = self.text_model.model(input_ids, attention_mask, positions, image_embeds, image_mask)
        return self.text_model.logits(hidden)


def build(cfg: Kosmos2Config, seed: int = 0) -> Kosmos2:
    """A freshly initialised model; initialisation runs as one compiled program (eager init
    compiles every small op separately, which takes seconds even for the tiny model)."""
    with _cheap_tracer_errors():
        return nnx.jit(lambda: Kosmos2(cfg, nnx.Rngs(seed)))()


@nnx.jit
def forward(model: Kosmos2, input_ids, attention_mask, image_mask, pixels=None, image_embeds=None):
    """`model(...)` compiled: logits [B, T, V]."""
    return model(input_ids, attention_mask, image_mask, pixels=pixels, image_embeds=image_embeds)


@nnx.jit
def image_embeds(model: Kosmos2, pixels):
    """`model.image_embeds(pixels)` compiled."""
    return model.image_embeds(pixels)


@contextlib.contextmanager
def _cheap_tracer_errors():
    """Flax reads `.sharding` of every traced value it stores (each RNG draw, each init); on a tracer
    jax answers AttributeError after building a message by walking the whole jaxpr, which makes
    eval_shape of the 24+24-layer model quadratic (tens of seconds). The message is never shown."""
    tracer = getattr(partial_eval, "DynamicJaxprTracer", None)
    original = getattr(tracer, "_origin_msg", None)
    if original is None:
        yield
        return
    tracer._origin_msg = lambda self: ""
    try:
        yield
    finally:
        tracer._origin_msg = original


def abstract_model(cfg: Kosmos2Config) -> Kosmos2:
    """The model with ShapeDtypeStructs instead of arrays (jax.eval_shape): nothing is allocated."""
    with _cheap_tracer_errors():
        return nnx.eval_shape(lambda: Kosmos2(cfg, nnx.Rngs(0)))


def split_model(model: nnx.Module) -> tuple[nnx.GraphDef, nnx.State, nnx.State]:
    """(graph definition, parameters, the rest: the dropout streams' keys and counts)."""
    return nnx.split(model, nnx.Param, ...)


def param_count(model_or_state) -> int:
    state = nnx.state(model_or_state, nnx.Param) if isinstance(model_or_state, nnx.Module) else model_or_state
    return int(sum(x.size for x in jax.tree.leaves(state)))
