"""Model sizes and run-time options of KOSMOS-2, convertible to and from transformers' config.json.

Sizes: `tiny` (transformers' own test sizes, for unit tests), `small` (a CPU demo), `kosmos2` (the
real microsoft/kosmos-2-patch14-224, whose weights can be imported).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class VisionConfig:
    hidden_size: int = 1024
    intermediate_size: int = 4096
    num_hidden_layers: int = 24
    num_attention_heads: int = 16
    num_channels: int = 3
    image_size: int = 224
    patch_size: int = 14
    layer_norm_eps: float = 1e-5
    attention_dropout: float = 0.0
    initializer_range: float = 0.02

    @property
    def num_patches(self) -> int:
        return (self.image_size // self.patch_size) ** 2

    @property
    def num_positions(self) -> int:
        return self.num_patches + 1  # the class token


@dataclasses.dataclass(frozen=True)
class TextConfig:
    vocab_size: int = 65037
    max_position_embeddings: int = 2048
    embed_dim: int = 2048
    layers: int = 24
    ffn_dim: int = 8192
    attention_heads: int = 32
    dropout: float = 0.1
    attention_dropout: float = 0.1
    activation_dropout: float = 0.0
    layer_norm_eps: float = 1e-5
    init_std: float = 0.02
    scale_embedding: bool = True
    pad_token_id: int = 1
    bos_token_id: int = 0
    eos_token_id: int = 2


ATTENTION_KERNELS = ("einsum", "fused")
REMAT_POLICIES = ("full", "dots")
DROPOUT_MASK_BITS = (32, 16, 8)  # layers.dropout_per_example's mask_bits
# config.json of a model transformers' KOSMOS-2 cannot compute (a grid code in its connector): a model
# type transformers does not know, so it refuses the folder instead of computing other embeddings.
EXTENDED_MODEL_TYPE = "kosmos_jax-kosmos-2"
EXTENSIONS_KEY = "kosmos_jax"
EXTENSION_FIELDS = ("connector_grid_code", "connector_instruction")


@dataclasses.dataclass(frozen=True)
class Kosmos2Config:
    vision: VisionConfig = VisionConfig()
    text: TextConfig = TextConfig()
    latent_query_num: int = 64
    # Run-time policy, not part of the checkpoint.
    compute_dtype: str = "float32"  # "float32" or "bfloat16"; params, softmax and LayerNorm stay float32
    magneto_init: bool = True  # scale decoder fc1/fc2/out_proj/v_proj by sqrt(log(2N)) at init
    # Init std of the connector's dense layer; None: text.init_std (0.02), KOSMOS-2's. Its inputs are
    # unit-norm vectors, so at 0.02 a model trained from scratch starts with image embeddings ~30x
    # below its text embeddings, and in 200 steps learns little from the image (tests/test_train_step.py).
    connector_dense_std: float | None = None
    # Amplitude of a fixed 2-D sin-cos code of each patch's grid cell, added to the connector's image
    # tokens after they are centred on the image's mean patch token; 0: KOSMOS-2's connector. From
    # scratch, a query's slot otherwise mixes the object's patch with what every patch shares, and the
    # decoder does not learn to read where the object is (results/demo/diagnosis.txt, section 6).
    connector_grid_code: float = 0.0
    # The latent queries also read the instruction (not KOSMOS-2; for models trained from scratch): the
    # mean embedding of the prompt's tokens after </image>, through a zero-initialised dense layer, is
    # added to every query, so the connector can look for the object an instruction names (on a mosaic,
    # one of four) where KOSMOS-2's queries are the same for every prompt.
    connector_instruction: bool = False
    # Blocks of each tower stacked on a leading `layers` axis and applied under nnx.scan: compile
    # time and program size stop growing with depth. Changes parameter paths, not values. Like every
    # nnx transform, scan and remat refuse variables made outside the current jax trace: inside raw
    # jax.jit/grad/lax.scan, call a model merged there (nnx.merge(..., copy=True) for closed-over state).
    scan_layers: bool = False
    remat: bool = False  # recompute each block's activations in the backward pass (less memory)
    # Under remat, what a block keeps for its backward pass: "full" nothing (its whole forward runs
    # again); "dots" the outputs of its dense layers (matmuls without batch dimensions), so that only
    # attention's batched products, the norms, activations and dropout are computed again.
    remat_policy: str = "full"
    # Random bits a training dropout mask draws an element (layers.dropout_per_example): 32 (a float32
    # uniform, the exact rate), 16 or 8 (the rate rounded to 1/65536 or 1/256; fewer bits to make).
    dropout_mask_bits: int = 32
    # "einsum": scores [B, H, T, S] made and kept in float32 (the program is plain XLA everywhere);
    # "fused": jax.nn.dot_product_attention, which picks cuDNN's flash kernel on a GPU where it can
    # (no scores kept) and XLA's elsewhere. An active attention dropout takes the einsum path: the
    # fused kernels draw no dropout.
    attention: str = "einsum"

    @property
    def dtype(self):
        if self.compute_dtype not in ("float32", "bfloat16"):
            raise ValueError(f"compute_dtype must be 'float32' or 'bfloat16', got {self.compute_dtype!r}")
        return jnp.dtype(self.compute_dtype)

    @property
    def magneto_gain(self) -> float:
        return math.sqrt(math.log(2 * self.text.layers)) if self.magneto_init else 1.0

    @property
    def connector_init_std(self) -> float:
        return self.text.init_std if self.connector_dense_std is None else self.connector_dense_std

    def replace(self, **changes) -> "Kosmos2Config":
        return dataclasses.replace(self, **changes)

    def __post_init__(self):
        if self.attention not in ATTENTION_KERNELS:
            raise ValueError(f"attention must be one of {ATTENTION_KERNELS}, got {self.attention!r}")
        if self.dropout_mask_bits not in DROPOUT_MASK_BITS:
            raise ValueError(f"dropout_mask_bits must be one of {DROPOUT_MASK_BITS}, got {self.dropout_mask_bits!r}")
        if self.remat_policy not in REMAT_POLICIES:
            raise ValueError(f"remat_policy must be one of {REMAT_POLICIES}, got {self.remat_policy!r}")

    def with_vocab_size(self, vocab_size: int) -> "Kosmos2Config":
        return self.replace(text=dataclasses.replace(self.text, vocab_size=vocab_size))

    # -- transformers' config.json ------------------------------------------------------------
    def to_hf_dict(self) -> dict[str, Any]:
        text = dataclasses.asdict(self.text)
        text.update(model_type="kosmos_2_text_model", activation_function="gelu", tie_word_embeddings=True)
        vision = dataclasses.asdict(self.vision)
        vision.update(model_type="kosmos_2_vision_model", hidden_act="quick_gelu")
        return {
            "architectures": ["Kosmos2ForConditionalGeneration"],
            "model_type": "kosmos-2",
            "latent_query_num": self.latent_query_num,
            "tie_word_embeddings": True,
            "text_config": text,
            "vision_config": vision,
        }

    @property
    def needs_extensions(self) -> bool:
        """Whether transformers' KOSMOS-2 would compute another model from to_hf_dict() alone."""
        return any(getattr(self, name) != getattr(Kosmos2Config, name) for name in EXTENSION_FIELDS)

    def to_extended_hf_dict(self) -> dict[str, Any]:
        """to_hf_dict() with this project's model type and the fields it lacks (EXTENSION_FIELDS) that differ
        from KOSMOS-2's (the others read back as their defaults)."""
        return {**self.to_hf_dict(), "model_type": EXTENDED_MODEL_TYPE,
                EXTENSIONS_KEY: {name: getattr(self, name) for name in EXTENSION_FIELDS
                                 if getattr(self, name) != getattr(Kosmos2Config, name)}}

    @classmethod
    def from_hf_dict(cls, data: dict[str, Any], source: str = "config.json", **runtime) -> "Kosmos2Config":
        """Read transformers' Kosmos2Config dict, or this project's extended one (to_extended_hf_dict);
        unknown keys are ignored, unsupported variants refused."""
        if data.get("model_type") not in (None, "kosmos-2", EXTENDED_MODEL_TYPE):
            raise ValueError(f"{source}: model_type is {data.get('model_type')!r}, expected 'kosmos-2' "
                             f"(or {EXTENDED_MODEL_TYPE!r}, this project's)")
        if data.get("model_type") == EXTENDED_MODEL_TYPE:
            runtime = {**_extensions(data.get(EXTENSIONS_KEY), source), **runtime}
        text_d, vision_d = dict(data.get("text_config") or {}), dict(data.get("vision_config") or {})
        act = text_d.get("activation_function", "gelu")
        if act != "gelu":
            raise ValueError(f"{source}: text_config.activation_function {act!r} unsupported (expected 'gelu')")
        vact = vision_d.get("hidden_act", "quick_gelu")
        if vact != "quick_gelu":
            raise ValueError(f"{source}: vision_config.hidden_act {vact!r} unsupported (expected 'quick_gelu')")
        if text_d.get("add_cross_attention"):
            raise ValueError(f"{source}: text_config.add_cross_attention is not supported")
        for name in ("image_size", "patch_size"):
            if isinstance(vision_d.get(name), (list, tuple)):
                sizes = set(vision_d[name])
                if len(sizes) != 1:
                    raise ValueError(f"{source}: non-square vision_config.{name} {vision_d[name]}")
                vision_d[name] = sizes.pop()
        text = TextConfig(**{f.name: text_d[f.name] for f in dataclasses.fields(TextConfig) if text_d.get(f.name) is not None})
        vision = VisionConfig(**{f.name: vision_d[f.name] for f in dataclasses.fields(VisionConfig) if f.name in vision_d})
        return cls(vision=vision, text=text, latent_query_num=data.get("latent_query_num", 64), **runtime)


def _extensions(block: Any, source: str) -> dict[str, Any]:
    if not isinstance(block, dict):
        raise ValueError(f"{source}: model_type {EXTENDED_MODEL_TYPE!r} needs a {EXTENSIONS_KEY!r} object")
    unknown = sorted(set(block) - set(EXTENSION_FIELDS))
    if unknown:  # a later version's extension: ignoring it would compute another model
        raise ValueError(f"{source}: unknown {EXTENSIONS_KEY} fields {unknown}; known: {list(EXTENSION_FIELDS)}")
    return dict(block)


# transformers' test sizes (tests/models/kosmos2/test_modeling_kosmos2.py), used by the parity fixture.
TINY = Kosmos2Config(
    vision=VisionConfig(hidden_size=32, intermediate_size=37, num_hidden_layers=2, num_attention_heads=4,
                        image_size=32, patch_size=4),
    text=TextConfig(vocab_size=99, max_position_embeddings=512, embed_dim=32, layers=2, ffn_dim=37,
                    attention_heads=4),
    latent_query_num=3,
)

# Large enough for a meaningful MFU figure and a demo on a laptop CPU, in seconds a step.
SMALL = Kosmos2Config(
    vision=VisionConfig(hidden_size=256, intermediate_size=1024, num_hidden_layers=4, num_attention_heads=4,
                        image_size=224, patch_size=14),
    text=TextConfig(vocab_size=65037, max_position_embeddings=2048, embed_dim=256, layers=4, ffn_dim=1024,
                    attention_heads=4),
    latent_query_num=64,
)

KOSMOS2 = Kosmos2Config()

SIZES = {"tiny": TINY, "small": SMALL, "kosmos2": KOSMOS2}


def get_config(size: str, **runtime) -> Kosmos2Config:
    if size not in SIZES:
        raise ValueError(f"unknown model size {size!r}; expected one of {sorted(SIZES)}")
    return SIZES[size].replace(**runtime)
