"""Scanned layers (blocks stacked on a `layers` axis under nnx.scan) and rematerialised blocks.

Both are run-time options: the same weights give the same logits, gradients, exports and decoded
tokens as the plain layout (tiny config, the committed parity fixture).
"""

import functools
import math
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax import nnx
from safetensors.numpy import load_file

from kosmos_jax.models import config as config_lib
from kosmos_jax.models import generation, sharding, weights
from kosmos_jax.models.decoder import TextTransformer
from kosmos_jax.models.kosmos2 import abstract_model, forward
from kosmos_jax.models.layers import scan_blocks

FIXTURE = pathlib.Path(__file__).parent / "fixtures" / "kosmos2_tiny"
TINY = config_lib.TINY
STACKED_Q_PROJ = ("text_model", "model", "layers", "self_attn", "q_proj", "kernel")


@pytest.fixture(scope="module")
def ref():
    return dict(np.load(FIXTURE / "reference.npz"))


def fixture_args(ref):
    return (jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool),
            jnp.asarray(ref["image_embeds_position_mask"], bool))


def pixels_of(ref):
    return jnp.asarray(ref["pixel_values"].transpose(0, 2, 3, 1))


def load(**runtime):
    model = weights.load_pretrained(FIXTURE, **runtime)
    model.eval()
    return model


def flat_params(model):
    return {path: np.asarray(var.get_value()) for path, var in nnx.to_flat_state(nnx.state(model, nnx.Param))}


def test_stacked_params_carry_the_layers_logical_axis():
    flat = dict(nnx.to_flat_state(nnx.state(abstract_model(TINY.replace(scan_layers=True)), nnx.Param)))
    plain = dict(nnx.to_flat_state(nnx.state(abstract_model(TINY), nnx.Param)))
    rules = dict(sharding.LOGICAL_AXIS_RULES)
    stacked = {path: var for path, var in flat.items() if "layers" in path}
    assert len(stacked) == len([p for p in plain if "layers" in p]) // 2  # two layers a tower in TINY
    for path, var in stacked.items():
        towers_layers = TINY.text.layers if path[0] == "text_model" else TINY.vision.num_hidden_layers
        axes = var.get_metadata()["logical_axes"]
        original = plain[(*path[:path.index("layers") + 1], 0, *path[path.index("layers") + 1:])]
        assert var.shape == (towers_layers, *original.shape), path
        assert axes == ("layers", *original.get_metadata()["logical_axes"]), path
        assert all(a in rules for a in axes)
    assert flat[STACKED_Q_PROJ].shape == (TINY.text.layers, 32, 32)
    assert {k: v for k, v in flat.items() if "layers" not in k}.keys() == {k for k in plain if "layers" not in k}


def test_scanned_logits_equal_the_plain_layout_and_the_pytorch_reference(ref):
    logits = {}
    for scan in (False, True):
        model = load(scan_layers=scan)
        logits[scan] = np.asarray(forward(model, *fixture_args(ref), pixels=pixels_of(ref)))
    real = ref["attention_mask"].astype(bool)
    np.testing.assert_allclose(logits[True][real], logits[False][real], atol=1e-5)
    assert np.abs(logits[True] - ref["logits"])[real].max() <= 1e-4


def test_layout_conversion_round_trips_params_and_rng_state():
    plain, scanned = load(), load(scan_layers=True)
    converted = weights.with_layout(plain, scan_layers=True)
    assert converted.config.scan_layers and not plain.config.scan_layers
    for path, value in flat_params(scanned).items():
        np.testing.assert_array_equal(flat_params(converted)[path], value, err_msg=str(path))
    back = weights.with_layout(converted, scan_layers=False)
    for kind in (nnx.Param, nnx.RngKey, nnx.RngCount):
        before = nnx.to_flat_state(nnx.state(plain, kind))
        after = dict(nnx.to_flat_state(nnx.state(back, kind)))
        assert len(before) == len(after) > 0
        for path, var in before:
            value = var.get_value()
            if kind is nnx.RngKey:
                value, other = jax.random.key_data(value), jax.random.key_data(after[path].get_value())
            else:
                other = after[path].get_value()
            np.testing.assert_array_equal(np.asarray(other), np.asarray(value), err_msg=str(path))


@pytest.mark.parametrize("max_shard_bytes", [None, 30_000])
def test_export_of_the_scanned_layout_writes_transformers_keys(tmp_path, max_shard_bytes):
    plain, scanned = load(), load(scan_layers=True)
    weights.save_pretrained(scanned, tmp_path / "scanned", max_shard_bytes=max_shard_bytes)
    weights.save_pretrained(plain, tmp_path / "plain", max_shard_bytes=max_shard_bytes)
    files = sorted(p.name for p in (tmp_path / "plain").iterdir())
    assert sorted(p.name for p in (tmp_path / "scanned").iterdir()) == files  # same shards, same index
    for name in files:
        assert (tmp_path / "scanned" / name).read_bytes() == (tmp_path / "plain" / name).read_bytes(), name
    theirs = load_file(FIXTURE / "model.safetensors")
    theirs.pop(weights.TIED_HEAD, None)
    ours = {}
    for file in (tmp_path / "scanned").glob("*.safetensors"):
        ours.update(load_file(file))
    assert set(ours) == set(theirs) and "text_model.model.layers.1.self_attn.q_proj.weight" in ours
    for key in theirs:
        np.testing.assert_array_equal(ours[key], theirs[key], err_msg=key)
    back = flat_params(weights.load_pretrained(tmp_path / "scanned", scan_layers=True))
    for path, value in flat_params(scanned).items():
        np.testing.assert_array_equal(back[path], value, err_msg=str(path))


def test_import_into_the_scanned_layout_names_a_bad_layer(tmp_path):
    weights.save_pretrained(load(), tmp_path)
    tensors = load_file(tmp_path / "model.safetensors")
    tensors["vision_model.model.encoder.layers.1.mlp.fc1.weight"] = np.zeros((36, 32), np.float32)
    from safetensors.numpy import save_file

    save_file(tensors, str(tmp_path / "model.safetensors"))
    with pytest.raises(ValueError, match=r"encoder.layers.1.mlp.fc1.weight has shape \(36, 32\).*\(37, 32\)"):
        weights.load_pretrained(tmp_path, scan_layers=True)
    del tensors["text_model.model.layers.0.ffn.fc2.bias"]
    save_file(tensors, str(tmp_path / "model.safetensors"))
    with pytest.raises(ValueError, match=r"missing \['text_model.model.layers.0.ffn.fc2.bias'\]"):
        weights.load_pretrained(tmp_path, scan_layers=True)


@pytest.mark.slow  # 31 s (make test's --durations, 2026-11-27 14:25, 2 cores)
def test_gradients_are_the_same_with_remat_and_scan_and_remat_checkpoints_every_block(ref):
    args, pixels = fixture_args(ref), pixels_of(ref)
    targets = jnp.roll(args[0], -1, axis=1)

    def loss_and_grads(model):
        graphdef, params, rest = nnx.split(model, nnx.Param, ...)

        def loss(params):  # a copy made here: nnx.scan and nnx.remat refuse variables of an outer trace
            logits = nnx.merge(graphdef, params, rest, copy=True)(*args, pixels=pixels)
            return optax.softmax_cross_entropy_with_integer_labels(logits, targets).mean()

        traced = jax.jit(jax.value_and_grad(loss)).trace(params)
        jaxpr = str(traced.jaxpr)
        value, grads = traced.lower().compile()(params)
        # unscanned grads keyed as the per-layer layout, so every variant compares with the plain one
        flat = weights.unstack_layers({path: np.asarray(g.get_value()) for path, g in nnx.to_flat_state(grads)})
        return jaxpr.count("remat2[") + jaxpr.count("checkpoint["), value, flat

    checkpoints, plain_loss, plain_grads = loss_and_grads(load())
    assert checkpoints == 0
    blocks = TINY.text.layers + TINY.vision.num_hidden_layers
    for scan, remat, policy, expected in ((False, True, "full", blocks), (True, False, "full", 0),
                                          (True, True, "full", 2), (True, True, "dots", 2)):  # 2: one a scan body
        checkpoints, value, grads = loss_and_grads(load(scan_layers=scan, remat=remat, remat_policy=policy))
        assert checkpoints == expected, (scan, remat, policy)
        np.testing.assert_allclose(value, plain_loss, rtol=1e-6)
        assert grads.keys() == plain_grads.keys()
        for path, grad in plain_grads.items():
            np.testing.assert_allclose(grads[path], grad, rtol=1e-5, atol=1e-7, err_msg=f"{scan=} {remat=} {policy=} {path}")


def test_cached_greedy_decoding_gives_the_same_tokens_in_both_layouts(ref):
    args = (*fixture_args(ref), jnp.asarray(ref["image_embeds"]))
    out = {}
    for scan in (False, True):
        model = load(scan_layers=scan)
        out[scan] = generation.generate(model, *args, max_new_tokens=4, return_logits=True)
        cache = nnx.eval_shape(lambda model: generation.prefill(model, *args, 16)[1], model)
        shape = (3, 16, TINY.text.attention_heads, TINY.text.embed_dim // TINY.text.attention_heads)
        if scan:
            assert cache["k"].shape == cache["v"].shape == (TINY.text.layers, *shape)
        else:
            assert [k.shape for k in cache["k"]] == [shape] * TINY.text.layers
    np.testing.assert_array_equal(np.asarray(out[True][0]), np.asarray(out[False][0]))
    np.testing.assert_allclose(np.asarray(out[True][1]), np.asarray(out[False][1]), atol=1e-5)
    assert len({tuple(row) for row in np.asarray(out[True][0])}) > 1  # rows decode differently: a real check


def test_dropout_masks_differ_between_scanned_layers(ref):
    model = load(scan_layers=True)
    model.train()
    ones = jnp.ones((4, 64), jnp.float32)

    @nnx.jit
    def masks(model):
        def probe(block, x, _):  # each layer's residual dropout applied to the same ones
            return x, block.dropout(ones) != 0

        return scan_blocks(probe, model.text_model.model.layers, jnp.zeros(()), None)[1]

    first, second = np.asarray(masks(model)), np.asarray(masks(model))
    assert first.shape == (TINY.text.layers, 4, 64)
    assert 0.05 < 1 - first.mean() < 0.2  # rate 0.1
    assert not np.array_equal(first[0], first[1])  # one mask a layer, not one for all
    assert not np.array_equal(first, second)  # and the stream advances between calls
    # the whole model in training mode: dropout inside both scans, the streams' counts carried out of jit
    a, b = (forward(model, *fixture_args(ref), pixels=pixels_of(ref)) for _ in range(2))
    assert np.isfinite(np.asarray(a)).all() and not np.allclose(a, b)


def test_fresh_scanned_init_has_distinct_layers_and_the_magneto_gain():
    gain = math.sqrt(math.log(2 * TINY.text.layers))

    def decoder(gain):
        return nnx.jit(lambda: TextTransformer(TINY.text, jnp.float32, nnx.Rngs(3), gain, scan_layers=True))().layers

    scaled, plain = decoder(gain), decoder(1.0)
    for name in ("ffn.fc1", "ffn.fc2", "self_attn.out_proj", "self_attn.v_proj"):
        got, base = (functools.reduce(getattr, name.split("."), m).kernel[...] for m in (scaled, plain))
        np.testing.assert_allclose(got, base * gain, rtol=1e-6, err_msg=name)
    np.testing.assert_array_equal(scaled.self_attn.q_proj.kernel[...], plain.self_attn.q_proj.kernel[...])
    q = np.asarray(plain.self_attn.q_proj.kernel[...])
    assert not np.allclose(q[0], q[1])  # every layer drew its own initial weights
    assert abs(q.std() - TINY.text.init_std) < 0.2 * TINY.text.init_std


def test_sharded_scanned_forward_on_a_fake_mesh_matches_unsharded(ref):
    if len(jax.devices()) < 8:
        pytest.skip("needs 8 (fake) devices")
    model = load(scan_layers=True)
    args, pixels = fixture_args(ref), pixels_of(ref)
    take = np.arange(4) % 3
    args, pixels = tuple(a[take] for a in args), pixels[take]
    expected = forward(model, *args, pixels=pixels)
    mesh = jax.make_mesh((2, 2, 2), sharding.MESH_AXES, axis_types=(jax.sharding.AxisType.Auto,) * 3)
    graphdef, state = nnx.split(model)
    state = jax.device_put(state, sharding.param_shardings(state, mesh))
    kernel = state["text_model"]["model"]["layers"]["self_attn"]["out_proj"]["kernel"]
    assert kernel.get_value().sharding.spec == jax.sharding.PartitionSpec(None, "tensor", "fsdp")

    @jax.jit
    def sharded_forward(state, ids, mask, image_mask, pixels):
        return nnx.merge(graphdef, state)(ids, mask, image_mask, pixels=pixels)

    with jax.set_mesh(mesh):
        got = sharded_forward(state, *args, pixels)
    np.testing.assert_allclose(np.asarray(got), np.asarray(expected), atol=2e-5)
