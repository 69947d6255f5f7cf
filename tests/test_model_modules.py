"""The model's structure: sizes, parameter count, logical axes, init switches, dtype policy."""

import json
import math
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx

import pathlib

from kosmos_jax.models import config as config_lib
from kosmos_jax.models import generation, sharding, weights
from kosmos_jax.models.decoder import TextBlock, init_cache
from kosmos_jax.models.kosmos2 import Kosmos2, abstract_model, build, forward, param_count
from kosmos_jax.models.summary import summarize

FIXTURE = pathlib.Path(__file__).parent / "fixtures" / "kosmos2_tiny"


def tiny_inputs(batch=None):
    """The parity fixture's inputs (same shapes in every test, so compiled forwards are reused)."""
    ref = np.load(FIXTURE / "reference.npz")
    ids, mask = jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool)
    image_mask = jnp.asarray(ref["image_embeds_position_mask"], bool)
    pixels = jnp.asarray(ref["pixel_values"].transpose(0, 2, 3, 1))
    if batch is not None:  # repeat rows to reach `batch`
        take = np.arange(batch) % ids.shape[0]
        ids, mask, image_mask, pixels = ids[take], mask[take], image_mask[take], pixels[take]
    return ids, mask, image_mask, pixels


def test_kosmos2_parameter_count_is_exact_from_shapes_only():
    summary = summarize(config_lib.get_config("kosmos2"))
    assert summary["total"] == 1_664_485_376
    # independent count by formula: vision tower, connector, decoder (tied head counted once)
    d, f, layers = 1024, 4096, 24
    vision = d + 3 * 14 * 14 * d + 257 * d + 2 * 2 * d + layers * (4 * (d * d + d) + d * f + f + f * d + d + 4 * d)
    t, tf = 2048, 8192
    connector = d * t + t + 64 * t + 4 * (t * t + t)
    text = 65037 * t + 2 * t + layers * (4 * (t * t + t) + 2 * t + 2 * t + t * tf + tf + tf * t + t + 2 * tf + 2 * t)
    assert vision + connector + text == summary["total"]
    assert summary["parts"]["text_model.embed_tokens (tied lm_head)"] == 65037 * t


def test_parameter_names_mirror_transformers_keys():
    flat = nnx.to_flat_state(nnx.state(abstract_model(config_lib.get_config("tiny")), nnx.Param))
    names = {".".join(map(str, path)) for path, _ in flat}
    for expected in (
        "vision_model.model.embeddings.patch_embedding.kernel",
        "vision_model.model.pre_layrnorm.scale",
        "vision_model.model.encoder.layers.1.self_attn.q_proj.kernel",
        "vision_model.model.post_layernorm.bias",
        "image_to_text_projection.latent_query",
        "image_to_text_projection.x_attn.out_proj.bias",
        "text_model.model.layers.0.self_attn.inner_attn_ln.scale",
        "text_model.model.layers.1.ffn.ffn_layernorm.bias",
        "text_model.model.layers.1.final_layer_norm.scale",
        "text_model.model.embed_tokens.embedding",
        "text_model.model.layer_norm.scale",
    ):
        assert expected in names, expected
    assert not any("lm_head" in n for n in names)  # tied to embed_tokens


def test_every_parameter_has_logical_axes_covered_by_the_rules():
    state = nnx.state(abstract_model(config_lib.get_config("tiny")), nnx.Param)
    rules = dict(sharding.LOGICAL_AXIS_RULES)
    for path, var in nnx.to_flat_state(state):
        axes = var.get_metadata().get("logical_axes")
        assert axes is not None and len(axes) == len(var.shape), path
        assert all(a in rules for a in axes), (path, axes)


def test_rules_map_to_mesh_axes_and_never_reuse_one():
    assert sharding.mesh_axes_for(("batch", "length", "act_embed")) == jax.sharding.PartitionSpec(("data", "fsdp"), None, None)
    assert sharding.mesh_axes_for(("embed", "mlp")) == jax.sharding.PartitionSpec("fsdp", "tensor")
    # batch takes fsdp first, so embed on the same array stays replicated rather than reusing fsdp
    assert sharding.mesh_axes_for(("batch", "embed")) == jax.sharding.PartitionSpec(("data", "fsdp"), None)
    with pytest.raises(KeyError, match="no_such_axis"):
        sharding.mesh_axes_for(("no_such_axis",))


def test_sharded_forward_on_a_fake_mesh_matches_unsharded():
    if len(jax.devices()) < 8:
        pytest.skip("needs 8 (fake) devices")
    model = weights.load_pretrained(FIXTURE)
    model.eval()
    ids, mask, image_mask, pixels = tiny_inputs(batch=4)
    expected = forward(model, ids, mask, image_mask, pixels=pixels)
    mesh = jax.make_mesh((2, 2, 2), sharding.MESH_AXES, axis_types=(jax.sharding.AxisType.Auto,) * 3)
    graphdef, state = nnx.split(model)
    shardings = sharding.param_shardings(state, mesh)
    state = jax.device_put(state, shardings)
    kernel = state["text_model"]["model"]["layers"][0]["self_attn"]["out_proj"]["kernel"]
    assert kernel.get_value().sharding.spec == jax.sharding.PartitionSpec("tensor", "fsdp")
    fc1 = state["text_model"]["model"]["layers"][0]["ffn"]["fc1"]["kernel"]  # 37 does not split in 2
    assert fc1.get_value().sharding.spec == jax.sharding.PartitionSpec("fsdp", None)

    @jax.jit
    def sharded_forward(state, ids, mask, image_mask, pixels):
        return nnx.merge(graphdef, state)(ids, mask, image_mask, pixels=pixels)

    with jax.set_mesh(mesh):
        got = sharded_forward(state, ids, mask, image_mask, pixels)
    np.testing.assert_allclose(np.asarray(got), np.asarray(expected), atol=2e-5)


def test_magneto_gain_scales_exactly_the_four_decoder_projections():
    cfg = config_lib.get_config("tiny")
    assert cfg.magneto_gain == pytest.approx(math.sqrt(math.log(2 * cfg.text.layers)))
    assert cfg.replace(magneto_init=False).magneto_gain == 1.0
    gain = 1.7
    plain = TextBlock(cfg.text, jnp.float32, nnx.Rngs(3), magneto_gain=1.0)
    scaled = TextBlock(cfg.text, jnp.float32, nnx.Rngs(3), magneto_gain=gain)
    for name in ("fc1", "fc2"):
        np.testing.assert_allclose(getattr(scaled.ffn, name).kernel[...], getattr(plain.ffn, name).kernel[...] * gain, rtol=1e-6)
    for name in ("out_proj", "v_proj"):
        np.testing.assert_allclose(getattr(scaled.self_attn, name).kernel[...], getattr(plain.self_attn, name).kernel[...] * gain, rtol=1e-6)
    for name in ("q_proj", "k_proj"):
        np.testing.assert_array_equal(getattr(scaled.self_attn, name).kernel[...], getattr(plain.self_attn, name).kernel[...])


def test_build_initialises_and_dropout_acts_only_in_training_mode():
    model = build(config_lib.get_config("tiny"))
    assert isinstance(model, Kosmos2)
    assert param_count(model) == summarize(config_lib.get_config("tiny"))["total"]
    ids, mask, image_mask, pixels = tiny_inputs()
    model.train()
    a, b = forward(model, ids, mask, image_mask, pixels=pixels), forward(model, ids, mask, image_mask, pixels=pixels)
    assert not np.allclose(a, b)
    model.eval()
    c, d = forward(model, ids, mask, image_mask, pixels=pixels), forward(model, ids, mask, image_mask, pixels=pixels)
    np.testing.assert_array_equal(c, d)


def test_bfloat16_compute_keeps_float32_params_and_logits_close():
    model32, model16 = weights.load_pretrained(FIXTURE), weights.load_pretrained(FIXTURE, compute_dtype="bfloat16")
    model32.eval(), model16.eval()
    assert {x.dtype for x in jax.tree.leaves(nnx.state(model16, nnx.Param))} == {jnp.dtype(jnp.float32)}
    ids, mask, image_mask, pixels = tiny_inputs()
    l32 = forward(model32, ids, mask, image_mask, pixels=pixels)
    l16 = forward(model16, ids, mask, image_mask, pixels=pixels)
    assert l16.dtype == jnp.float32
    assert float(jnp.max(jnp.abs(l32 - l16))) < 0.1 * float(jnp.max(jnp.abs(l32)))
    with pytest.raises(ValueError, match="float16"):
        _ = model32.config.replace(compute_dtype="float16").dtype


def test_unknown_size_is_refused():
    with pytest.raises(ValueError, match="huge"):
        config_lib.get_config("huge")


def test_summary_cli_prints_json(capsys):
    import json

    from kosmos_jax.models import summary

    summary.main(["--size", "tiny"])
    printed = json.loads(capsys.readouterr().out)
    assert printed["size"] == "tiny" and printed["total"] == sum(printed["parts"].values()) == 39816


def test_config_json_round_trip_and_refusals():
    cfg = config_lib.get_config("kosmos2")
    assert config_lib.Kosmos2Config.from_hf_dict(cfg.to_hf_dict()) == cfg
    with pytest.raises(ValueError, match="model_type is 'clip'"):
        config_lib.Kosmos2Config.from_hf_dict({"model_type": "clip"}, source="x/config.json")
    bad = cfg.to_hf_dict()
    bad["text_config"]["activation_function"] = "relu"
    with pytest.raises(ValueError, match="x/config.json.*relu"):
        config_lib.Kosmos2Config.from_hf_dict(bad, source="x/config.json")


def test_vision_attention_dropout_follows_the_config_in_training_mode_only(tmp_path):
    config = json.loads((FIXTURE / "config.json").read_text())
    assert config["vision_config"]["attention_dropout"] == 0.1  # transformers' test config
    config["vision_config"]["attention_dropout"] = 0.0
    for name in ("config.json", "model.safetensors"):
        shutil.copy(FIXTURE / name, tmp_path / name)
    (tmp_path / "config.json").write_text(json.dumps(config))
    pixels = tiny_inputs()[3]
    run = nnx.jit(lambda model, pixels: model.vision_model(pixels))

    def features(folder, train):
        model = weights.load_pretrained(folder)
        model.train() if train else model.eval()
        return np.asarray(run(model, pixels)), np.asarray(run(model, pixels))

    evaluated, _ = features(FIXTURE, train=False)
    np.testing.assert_array_equal(features(tmp_path, train=True)[0], evaluated)  # rate 0: no other dropout
    first, second = features(FIXTURE, train=True)
    assert not np.allclose(first, evaluated) and not np.allclose(first, second)


def test_kv_cache_and_connector_output_follow_the_rules_and_every_rule_is_used(monkeypatch):
    if len(jax.devices()) < 8:
        pytest.skip("needs 8 (fake) devices")
    model = weights.load_pretrained(FIXTURE)
    model.eval()
    ids, mask, image_mask, pixels = tiny_inputs(batch=4)
    expected = generation.prefill(model, ids, mask, image_mask, model.image_embeds(pixels), ids.shape[1] + 2)[0]
    activation_names = set()
    original = sharding.mesh_axes_for

    def recording(logical, *args, **kwargs):
        activation_names.update(name for name in logical if name is not None)
        return original(logical, *args, **kwargs)

    monkeypatch.setattr(sharding, "mesh_axes_for", recording)
    mesh = jax.make_mesh((2, 2, 2), sharding.MESH_AXES, axis_types=(jax.sharding.AxisType.Auto,) * 3)
    graphdef, state = nnx.split(model)
    state = jax.device_put(state, sharding.param_shardings(state, mesh))

    @jax.jit
    def embeds_and_prefill(state, ids, mask, image_mask, pixels):
        model = nnx.merge(graphdef, state)
        embeds = model.image_embeds(pixels)
        logits, cache, _ = generation.prefill(model, ids, mask, image_mask, embeds, ids.shape[1] + 2)
        return embeds, logits, cache

    with jax.set_mesh(mesh):
        embeds, logits, cache = embeds_and_prefill(state, ids, mask, image_mask, pixels)
        fresh = jax.jit(lambda: init_cache(model.config.text, 4, 8))()
    def placed(array, *spec):
        return array.sharding.is_equivalent_to(jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(*spec)), array.ndim)

    batch = ("data", "fsdp")
    assert placed(embeds, batch, None, None)
    for array in cache["k"] + cache["v"] + fresh["k"] + fresh["v"]:  # [B, slots, heads, head_dim]
        assert placed(array, batch, None, "tensor", None)  # heads split as the attention splits them
    assert placed(fresh["valid"], batch, None)
    np.testing.assert_allclose(np.asarray(logits), np.asarray(expected), atol=2e-5)
    scanned = abstract_model(model.config.replace(scan_layers=True))  # adds the stacked blocks' `layers`
    param_names = {name for layout in (model, scanned) for _, var in nnx.to_flat_state(nnx.state(layout, nnx.Param))
                   for name in var.get_metadata()["logical_axes"]}
    assert {name for name, _ in sharding.LOGICAL_AXIS_RULES} == param_names | activation_names
