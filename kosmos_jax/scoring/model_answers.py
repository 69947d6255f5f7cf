"""Answers of a model given as parameters on a mesh (greedy, or chosen by a picker): one jitted
program per prompt shape and constraint, images to tokens (pixels, image embeddings, KV-cache decoding).

The parameters stay where they are (a trainer's fsdp shards, a restored checkpoint's); prompts and
images go in replicated, and the answers come back replicated, so every process of a multi-process
run takes part in the same program and reads every row.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from kosmos_jax.models import generation
from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.kosmos2 import abstract_model
from kosmos_jax.models.preprocess import pixels


def fixed_streams(rest: nnx.State) -> nnx.State:
    """Values for the model's non-parameter state (its dropout streams), from their shapes only.
    Decoding runs with dropout off, so the streams are never drawn from; nnx.merge needs them."""

    def concrete(variable):
        if isinstance(variable, nnx.RngKey):
            keys = jax.random.split(jax.random.key(0), max(1, math.prod(variable.shape)))
            return variable.replace(keys.reshape(variable.shape))
        return variable.replace(jnp.zeros(variable.shape, variable.dtype))

    return jax.tree.map(concrete, rest, is_leaf=lambda x: isinstance(x, nnx.Variable))


def answers_program(graphdef, rest, params, images, ids, mask, image_mask, *, constraint, max_new_tokens, picker,
                    return_logits: bool = False):
    """The generated tokens of a batch of prompts with their images (and each step's logits if asked), for jit."""
    model = nnx.view(nnx.merge(graphdef, params, fixed_streams(rest)), deterministic=True)
    embeds = model.image_embeds(pixels(images, model.config.vision.image_size), model.instruction_bag(ids, mask, image_mask))
    return generation.generate(model, ids, mask, image_mask, embeds, max_new_tokens=max_new_tokens, constraint=constraint,
                               picker=picker, return_logits=return_logits)


class Decoder:
    """`decoder(params, images, ids, mask, image_mask, constraint, max_new_tokens)` -> generated ids
    [B, max_new_tokens] as numpy (pad id after each row's EOS); `constraint` None decodes freely. A
    `picker` (`models.value_decoding.LocalMean`) chooses each token instead of the greedy mode."""

    def __init__(self, model_config: Kosmos2Config, mesh: Mesh, picker=None):
        graphdef, _, rest = nnx.split(abstract_model(model_config), nnx.Param, ...)
        self.replicated = NamedSharding(mesh, PartitionSpec())
        self._jitted = jax.jit(functools.partial(answers_program, graphdef, rest, picker=picker),
                               static_argnames=("constraint", "max_new_tokens"), out_shardings=self.replicated)

    def _global(self, array: np.ndarray) -> jax.Array:
        # every process holds the whole batch: a replicated global array of it
        return jax.make_array_from_process_local_data(self.replicated, np.asarray(array), np.shape(array))

    def __call__(self, params, images, ids, mask, image_mask, constraint, max_new_tokens: int) -> np.ndarray:
        inputs = [self._global(x) for x in (images, ids, mask, image_mask)]
        tokens = self._jitted(params, *inputs, constraint=constraint, max_new_tokens=max_new_tokens)
        return np.asarray(tokens.addressable_data(0))
