"""Greedy generation inside jit: with a key-value cache (static shapes) or by recomputing everything.

Batched prompts are LEFT-padded (attention_mask 0, pad id 1). Positions follow KOSMOS-2: the first
real token of every row is at position 2 and each real token adds one, so a left-padded row decodes
exactly as it would alone. (transformers' `generate` instead adds the padding length to the
positions of generated tokens; see tests/test_model_generation.py.)

A `constraint` (the interface of NoConstraint; kosmos_jax.models.grammar.TokenConstraint for grasp
answers) restricts every step to the tokens it allows, told how many tokens the row may still emit
(this one included) so that it can keep only tokens after which an answer still fits. After its
EOS a row emits the pad id, and those pad tokens are padding in both paths: never attended to, at
the padding position.
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.decoder import init_cache, position_ids
from kosmos_jax.models.kosmos2 import Kosmos2
from kosmos_jax.models.value_decoding import greedy


class NoConstraint:
    """Every token allowed; the interface a grammar constraint implements."""

    min_tokens = 0  # the fewest new tokens (EOS included) a complete answer takes

    def init(self, batch: int) -> Any:
        return jnp.zeros((batch,), jnp.int32)

    def allowed(self, state, vocab_size: int, remaining) -> jax.Array:
        """[B, V] bool; `remaining` (int32 scalar): tokens the row may still emit, this one included."""
        return jnp.ones((state.shape[0], vocab_size), bool)

    def advance(self, state, tokens):
        return state

    def finished(self, state) -> jax.Array:
        return jnp.zeros(state.shape, bool)


def _pick(logits, constraint, cstate, done, remaining, eos_id, pad_id, picker):
    allowed = constraint.allowed(cstate, logits.shape[-1], remaining)
    token = picker.pick(logits, allowed) if picker is not None else greedy(logits, allowed)
    token = jnp.where(done, pad_id, token)
    cstate = constraint.advance(cstate, token)
    done = done | (token == eos_id) | constraint.finished(cstate)
    return token, cstate, done


def prefill(model: Kosmos2, input_ids, attention_mask, image_mask, image_embeds, max_len: int):
    """Run the prompt through the decoder, filling slots [0, T) of a fresh cache of `max_len` slots."""
    cfg = model.config.text
    attention_mask = attention_mask.astype(bool)
    cache = init_cache(cfg, input_ids.shape[0], max_len, model.config.dtype, stacked=model.config.scan_layers)
    positions = position_ids(attention_mask, cfg.pad_token_id)
    hidden, cache = model.text_model.model(input_ids, attention_mask, positions, image_embeds, image_mask, cache)
    logits = model.text_model.logits(hidden[:, -1:])[:, 0]
    return logits, cache, attention_mask.sum(axis=1).astype(jnp.int32)


def step(model: Kosmos2, tokens, valid, cache, n_real):
    """One new token per row at slot cache['index']; returns (logits [B, V], cache, n_real).

    valid [B] bool: False for padding after a row's EOS (not attended to, padding position)."""
    cfg = model.config.text
    real = valid[:, None]
    positions = position_ids(real, cfg.pad_token_id, start=n_real)
    hidden, cache = model.text_model.model(tokens[:, None], real, positions, cache=cache)
    return model.text_model.logits(hidden)[:, 0], cache, n_real + valid.astype(jnp.int32)


@functools.partial(nnx.jit, static_argnames=("max_new_tokens", "constraint", "use_cache", "return_logits", "picker"))
def generate(model: Kosmos2, input_ids, attention_mask, image_mask, image_embeds, *, max_new_tokens: int,
             constraint=None, use_cache: bool = True, return_logits: bool = False, picker=None):
    """Greedy tokens [B, max_new_tokens] (pad id after a row's EOS), and per-step logits if asked.
    A `picker` (`value_decoding.LocalMean`) chooses each token among the allowed ones instead of the mode."""
    constraint = constraint or NoConstraint()
    if max_new_tokens < 1:
        raise ValueError(f"max_new_tokens must be positive, got {max_new_tokens}")
    if max_new_tokens < constraint.min_tokens:
        raise ValueError(f"max_new_tokens={max_new_tokens} is too few: the shortest answer the constraint "
                         f"allows takes {constraint.min_tokens} tokens (EOS included)")
    cfg = model.config.text
    batch, prompt_len = input_ids.shape
    # The loop bodies below use a copy of the model made inside them: nnx transforms within the model
    # (nnx.scan over scanned layers) refuse variables created outside the jax.lax.scan trace.
    graphdef, state = nnx.split(model)
    cstate = constraint.init(batch)
    done = jnp.zeros((batch,), bool)
    if use_cache:
        logits, cache, n_real = prefill(model, input_ids, attention_mask, image_mask, image_embeds,
                                        prompt_len + max_new_tokens)
        token, cstate, done = _pick(logits, constraint, cstate, done, max_new_tokens, cfg.eos_token_id,
                                    cfg.pad_token_id, picker)

        def body(carry, i):
            token, valid, cache, n_real, cstate, done = carry  # valid: `token` came before the row's EOS
            logits, cache, n_real = step(nnx.merge(graphdef, state, copy=True), token, valid, cache, n_real)
            new, cstate, new_done = _pick(logits, constraint, cstate, done, max_new_tokens - i, cfg.eos_token_id,
                                          cfg.pad_token_id, picker)
            return (new, ~done, cache, n_real, cstate, new_done), (new, logits)

        carry = (token, jnp.ones((batch,), bool), cache, n_real, cstate, done)
        _, (tokens, step_logits) = jax.lax.scan(body, carry, jnp.arange(1, max_new_tokens))
        tokens = jnp.concatenate([token[None], tokens], axis=0).T
        all_logits = jnp.concatenate([logits[None], step_logits], axis=0).transpose(1, 0, 2)
    else:
        ids = jnp.concatenate([input_ids, jnp.full((batch, max_new_tokens), cfg.pad_token_id, input_ids.dtype)], 1)
        mask = jnp.concatenate([attention_mask.astype(bool), jnp.zeros((batch, max_new_tokens), bool)], 1)
        image_mask = jnp.concatenate([image_mask.astype(bool), jnp.zeros((batch, max_new_tokens), bool)], 1)

        def body(carry, i):
            ids, mask, cstate, done = carry
            logits = nnx.merge(graphdef, state, copy=True)(ids, mask, image_mask, image_embeds=image_embeds)
            logits = jax.lax.dynamic_index_in_dim(logits, prompt_len + i - 1, axis=1, keepdims=False)
            token, cstate, done_new = _pick(logits, constraint, cstate, done, max_new_tokens - i, cfg.eos_token_id,
                                            cfg.pad_token_id, picker)
            ids = jax.lax.dynamic_update_slice(ids, token[:, None].astype(ids.dtype), (0, prompt_len + i))
            mask = jax.lax.dynamic_update_slice(mask, ~done[:, None], (0, prompt_len + i))
            return (ids, mask, cstate, done_new), (token, logits)

        _, (tokens, all_logits) = jax.lax.scan(body, (ids, mask, cstate, done), jnp.arange(max_new_tokens))
        tokens, all_logits = tokens.T, all_logits.transpose(1, 0, 2)
    return (tokens, all_logits) if return_logits else tokens
