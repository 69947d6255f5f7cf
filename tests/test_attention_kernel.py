"""`Kosmos2Config.attention`: "fused" (jax.nn.dot_product_attention) against "einsum" (our own).

On the CPU jax's fused attention is its XLA implementation; cuDNN's kernel is chosen on a GPU only.
Parity here checks the arguments we hand over (layout, scale, mask, the rows with no allowed key)
and the fallback to einsum while attention dropout is active.
"""

import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import nnx

from kosmos_jax.models import config as config_lib
from kosmos_jax.models import weights
from kosmos_jax.models.kosmos2 import forward
from kosmos_jax.models.layers import Dropout, dot_product_attention

FIXTURE = pathlib.Path(__file__).parent / "fixtures" / "kosmos2_tiny"


def qkv_and_mask(dtype):
    keys = jax.random.split(jax.random.key(0), 3)
    q, k, v = (jax.random.normal(key, (2, 6, 3, 8), dtype) for key in keys)
    causal = jnp.tril(jnp.ones((6, 6), bool))
    padding = jnp.array([[True] * 6, [False, True, True, True, False, False]])  # example 1: no key for query 0
    return q, k, v, causal[None, None] & padding[:, None, None, :]


def test_fused_attention_equals_einsum_with_a_mask_and_a_row_with_no_allowed_key():
    q, k, v, mask = qkv_and_mask(jnp.float32)
    einsum = np.asarray(dot_product_attention(q, k, v, mask))
    fused = np.asarray(dot_product_attention(q, k, v, mask, kernel="fused"))
    # float32, 8-term dot products and a softmax over 6 keys: a few ulps of values of order 1
    np.testing.assert_allclose(fused, einsum, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(fused[1, 0], np.asarray(v[1].mean(axis=0)), rtol=1e-5, atol=1e-6)  # uniform row
    no_mask = dot_product_attention(q, k, v, None, kernel="fused")
    np.testing.assert_allclose(np.asarray(no_mask), np.asarray(dot_product_attention(q, k, v, None)), rtol=1e-5, atol=1e-6)


def test_fused_attention_in_bfloat16_is_within_its_resolution():
    q, k, v, mask = qkv_and_mask(jnp.bfloat16)
    einsum = np.asarray(dot_product_attention(q, k, v, mask), np.float32)
    fused = np.asarray(dot_product_attention(q, k, v, mask, kernel="fused"), np.float32)
    resolution = 2.0**-8  # bfloat16 keeps 8 significant bits: outputs rounded once, probabilities once
    np.testing.assert_allclose(fused, einsum, rtol=4 * resolution, atol=4 * resolution)


def test_active_attention_dropout_takes_the_einsum_path():
    q, k, v, mask = qkv_and_mask(jnp.float32)
    dropout = Dropout(0.5, rngs=nnx.Rngs(dropout=1))
    einsum = dot_product_attention(q, k, v, mask, Dropout(0.5, rngs=nnx.Rngs(dropout=1)))
    fused = dot_product_attention(q, k, v, mask, dropout, kernel="fused")
    np.testing.assert_array_equal(np.asarray(fused), np.asarray(einsum))  # the same masks drawn
    dropout.eval()
    np.testing.assert_allclose(np.asarray(dot_product_attention(q, k, v, mask, dropout, kernel="fused")),
                               np.asarray(dot_product_attention(q, k, v, mask)), rtol=1e-5, atol=1e-6)


@pytest.mark.slow  # 26 s (make test's --durations, 2026-11-28, 2 cores)
def test_the_model_with_fused_attention_matches_the_pytorch_reference_and_its_gradients_the_einsum_model():
    ref = dict(np.load(FIXTURE / "reference.npz"))
    args = (jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool),
            jnp.asarray(ref["image_embeds_position_mask"], bool))
    pixels = jnp.asarray(ref["pixel_values"].transpose(0, 2, 3, 1))
    real = ref["attention_mask"].astype(bool)
    targets = jnp.roll(args[0], -1, axis=1)
    results = {}
    for kernel in ("einsum", "fused"):
        model = weights.load_pretrained(FIXTURE, attention=kernel)
        model.eval()
        logits = np.asarray(forward(model, *args, pixels=pixels))
        graphdef, params, rest = nnx.split(model, nnx.Param, ...)

        def loss(params):
            out = nnx.merge(graphdef, params, rest, copy=True)(*args, pixels=pixels)
            return optax.softmax_cross_entropy_with_integer_labels(out, targets).mean()

        grads = jax.jit(jax.grad(loss))(params)
        results[kernel] = logits, {path: np.asarray(g.get_value()) for path, g in nnx.to_flat_state(grads)}
    assert np.abs(results["fused"][0] - ref["logits"])[real].max() <= 1e-4  # the einsum model's own bound
    np.testing.assert_allclose(results["fused"][0][real], results["einsum"][0][real], atol=1e-5)
    for path, grad in results["einsum"][1].items():
        np.testing.assert_allclose(results["fused"][1][path], grad, rtol=1e-5, atol=1e-7, err_msg=str(path))


def test_an_unknown_attention_kernel_is_refused():
    with pytest.raises(ValueError, match="attention must be one of .*'flash'"):
        config_lib.TINY.replace(attention="flash")
