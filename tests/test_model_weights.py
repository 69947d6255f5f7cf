"""Weight import/export in transformers' layout (no torch) and vocabulary growth."""

import json
import pathlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from safetensors.numpy import load_file, save_file

from kosmos_jax.models import weights
from kosmos_jax.models.config import EXTENDED_MODEL_TYPE, TINY, Kosmos2Config
from kosmos_jax.models.kosmos2 import build, forward

FIXTURE = pathlib.Path(__file__).parent / "fixtures" / "kosmos2_tiny"


def params_of(model):
    return {".".join(map(str, p)): np.asarray(v.get_value()) for p, v in nnx.to_flat_state(nnx.state(model, nnx.Param))}


def test_export_writes_exactly_transformers_keys_and_layouts(tmp_path):
    model = weights.load_pretrained(FIXTURE)
    weights.save_pretrained(model, tmp_path)
    ours, theirs = load_file(tmp_path / "model.safetensors"), load_file(FIXTURE / "model.safetensors")
    theirs.pop(weights.TIED_HEAD, None)
    assert set(ours) == set(theirs)
    for key in theirs:
        np.testing.assert_array_equal(ours[key], theirs[key], err_msg=key)
    config = json.loads((tmp_path / "config.json").read_text())
    fixture_config = json.loads((FIXTURE / "config.json").read_text())
    for key in ("embed_dim", "layers", "ffn_dim", "attention_heads", "vocab_size", "layer_norm_eps"):
        assert config["text_config"][key] == fixture_config["text_config"][key]
    assert config["latent_query_num"] == fixture_config["latent_query_num"]


@pytest.mark.parametrize("max_shard_bytes", [None, 30_000])
def test_round_trip_single_file_and_sharded(tmp_path, max_shard_bytes):
    model = weights.load_pretrained(FIXTURE)
    weights.save_pretrained(model, tmp_path, max_shard_bytes=max_shard_bytes)
    if max_shard_bytes:
        index = json.loads((tmp_path / "model.safetensors.index.json").read_text())
        assert len(set(index["weight_map"].values())) > 1
        assert not (tmp_path / "model.safetensors").exists()
    back = params_of(weights.load_pretrained(tmp_path))
    for key, value in params_of(model).items():
        np.testing.assert_array_equal(back[key], value, err_msg=key)


def test_import_errors_name_the_file_and_the_keys(tmp_path):
    weights.save_pretrained(weights.load_pretrained(FIXTURE), tmp_path)
    tensors = load_file(tmp_path / "model.safetensors")
    tensors.pop("text_model.model.layer_norm.weight")
    tensors["text_model.model.surprise.weight"] = np.zeros(3, np.float32)
    save_file(tensors, str(tmp_path / "model.safetensors"))
    with pytest.raises(ValueError, match=r"missing \['text_model.model.layer_norm.weight'\].*surprise"):
        weights.load_pretrained(tmp_path)
    with pytest.raises(FileNotFoundError, match="config.json"):
        weights.load_pretrained(tmp_path / "nowhere")


def test_import_refuses_wrong_shapes_and_untied_heads(tmp_path):
    weights.save_pretrained(weights.load_pretrained(FIXTURE), tmp_path)
    tensors = load_file(tmp_path / "model.safetensors")
    good = dict(tensors)
    tensors["text_model.model.layers.0.ffn.fc1.weight"] = np.zeros((36, 32), np.float32)
    save_file(tensors, str(tmp_path / "model.safetensors"))
    with pytest.raises(ValueError, match=r"fc1.weight has shape \(36, 32\).*\(37, 32\)"):
        weights.load_pretrained(tmp_path)
    good[weights.TIED_HEAD] = good[weights.EMBED_TOKENS] + 1.0
    save_file(good, str(tmp_path / "model.safetensors"))
    with pytest.raises(ValueError, match="untied"):
        weights.load_pretrained(tmp_path)


def test_vocabulary_growth_keeps_old_logits_and_starts_new_tokens_at_the_mean(tmp_path):
    model = weights.load_pretrained(FIXTURE)
    model.eval()
    ref = dict(np.load(FIXTURE / "reference.npz"))
    args = (jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool),
            jnp.asarray(ref["image_embeds_position_mask"], bool))
    before = np.asarray(forward(model, *args, image_embeds=jnp.asarray(ref["image_embeds"])))
    old_table = np.asarray(model.text_model.model.embed_tokens.embedding.get_value())
    weights.grow_vocabulary(model, 99 + 5, seed=1)
    assert model.config.text.vocab_size == 104
    after = np.asarray(forward(model, *args, image_embeds=jnp.asarray(ref["image_embeds"])))
    assert after.shape[-1] == 104
    np.testing.assert_allclose(after[..., :99], before, atol=1e-5)  # old rows and the old model unchanged
    new_rows = np.asarray(model.text_model.model.embed_tokens.embedding.get_value())[99:]
    np.testing.assert_allclose(new_rows, np.broadcast_to(old_table.mean(0), new_rows.shape), atol=1e-2 * old_table.std())
    assert len({row.tobytes() for row in new_rows}) == 5  # distinct, so the new tokens can be told apart
    # new tokens' logits sit near the mean logit, not at an extreme
    real = ref["attention_mask"].astype(bool)
    new_logits, old_logits = after[..., 99:][real], before[real]
    assert np.all(np.abs(new_logits - old_logits.mean(-1, keepdims=True)) < 3 * old_logits.std(-1, keepdims=True))
    # the grown model exports and imports with its new size
    weights.save_pretrained(model, tmp_path)
    assert weights.read_config(tmp_path).text.vocab_size == 104
    np.testing.assert_array_equal(params_of(weights.load_pretrained(tmp_path))["text_model.model.embed_tokens.embedding"],
                                  np.asarray(model.text_model.model.embed_tokens.embedding.get_value()))
    with pytest.raises(ValueError, match="smaller"):
        weights.grow_vocabulary(model, 50)


def test_rng_state_is_filled_so_training_mode_works():
    model = weights.load_pretrained(FIXTURE)
    model.train()
    ref = dict(np.load(FIXTURE / "reference.npz"))
    args = (jnp.asarray(ref["input_ids"]), jnp.asarray(ref["attention_mask"], bool),
            jnp.asarray(ref["image_embeds_position_mask"], bool))
    first = forward(model, *args, image_embeds=jnp.asarray(ref["image_embeds"]))
    second = forward(model, *args, image_embeds=jnp.asarray(ref["image_embeds"]))
    assert np.isfinite(np.asarray(first)).all() and not np.allclose(first, second)
    assert jax.tree.leaves(nnx.state(model, nnx.RngKey))


def test_vocabulary_growth_from_source_pieces():
    model = weights.load_pretrained(FIXTURE)
    table = np.asarray(model.text_model.model.embed_tokens.embedding.get_value())
    weights.grow_vocabulary(model, 101, noise=0.0, source_ids=[[10, 11, 12], [40]])
    grown = np.asarray(model.text_model.model.embed_tokens.embedding.get_value())
    np.testing.assert_allclose(grown[99], table[[10, 11, 12]].mean(0), rtol=1e-6)
    np.testing.assert_array_equal(grown[100], table[40])
    with pytest.raises(ValueError, match=r"outside the current vocabulary of 101"):
        weights.grow_vocabulary(model, 102, source_ids=[[500]])
    with pytest.raises(ValueError, match="needs 1 non-empty"):
        weights.grow_vocabulary(model, 102, source_ids=[[1], [2]])


@pytest.mark.parametrize("dtype,max_shard_bytes", [(jnp.bfloat16, None), (np.float16, 20_000)])
def test_half_precision_checkpoints_import_as_float32(tmp_path, dtype, max_shard_bytes):
    """transformers' hub checkpoints are often bf16 or fp16; they import exactly (as float32)."""
    model = weights.load_pretrained(FIXTURE)
    weights.save_pretrained(model, tmp_path, max_shard_bytes=max_shard_bytes)
    halves = {}
    for file in sorted(tmp_path.glob("*.safetensors")):
        tensors = load_file(file)
        if file.name == "model.safetensors":  # the tied head, stored as transformers does
            tensors[weights.TIED_HEAD] = tensors[weights.EMBED_TOKENS]
        halves.update({key: value.astype(dtype) for key, value in tensors.items()})
        save_file({key: halves[key] for key in tensors}, str(file))
    assert {value.dtype for value in weights.read_tensors(tmp_path).values()} == {np.dtype(dtype)}  # no copy yet
    back = params_of(weights.load_pretrained(tmp_path))
    assert {value.dtype for value in back.values()} == {np.dtype(np.float32)}
    for path, value in params_of(model).items():
        key = weights.hf_key(tuple(path.split(".")))
        expected = weights.from_hf(tuple(path.split(".")), halves[key].astype(np.float32))
        np.testing.assert_array_equal(back[path], expected, err_msg=path)


@pytest.mark.slow  # 16 s (make test's --durations, 2026-11-28, 2 cores)
def test_a_grid_code_model_is_written_only_on_opt_in_and_a_kosmos_2_one_alike_either_way(tmp_path):
    grid = build(TINY.replace(connector_grid_code=3.0))
    with pytest.raises(ValueError, match=r"extensions=True"):
        weights.save_pretrained(grid, tmp_path / "refused")
    assert not (tmp_path / "refused").exists()
    weights.save_pretrained(grid, tmp_path / "grid", extensions=True)
    written = json.loads((tmp_path / "grid" / "config.json").read_text())
    assert written["model_type"] == EXTENDED_MODEL_TYPE and written["kosmos_jax"] == {"connector_grid_code": 3.0}
    assert weights.read_config(tmp_path / "grid").connector_grid_code == 3.0
    plain = build(TINY)
    weights.save_pretrained(plain, tmp_path / "plain")
    weights.save_pretrained(plain, tmp_path / "opted", extensions=True)
    for name in ("config.json", "model.safetensors"):
        assert (tmp_path / "plain" / name).read_bytes() == (tmp_path / "opted" / name).read_bytes()
    assert json.loads((tmp_path / "plain" / "config.json").read_text()) == TINY.to_hf_dict()


def test_from_hf_dict_refuses_other_model_types_and_unknown_extensions():
    data = TINY.to_hf_dict()
    with pytest.raises(ValueError, match=r"model_type is 'llava'.*expected 'kosmos-2'"):
        Kosmos2Config.from_hf_dict({**data, "model_type": "llava"})
    extended = TINY.replace(connector_grid_code=2.0).to_extended_hf_dict()
    assert Kosmos2Config.from_hf_dict(extended) == TINY.replace(connector_grid_code=2.0)
    assert Kosmos2Config.from_hf_dict(data) == TINY  # no extension block: KOSMOS-2's connector
    with pytest.raises(ValueError, match=r"unknown kosmos_jax fields \['warp'\]"):
        Kosmos2Config.from_hf_dict({**extended, "kosmos_jax": {"connector_grid_code": 2.0, "warp": 1}})
    with pytest.raises(ValueError, match="needs a 'kosmos_jax' object"):
        Kosmos2Config.from_hf_dict({**data, "model_type": EXTENDED_MODEL_TYPE})
