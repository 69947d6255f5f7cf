"""A connector whose latent queries also read the instruction (model option connector_instruction)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from kosmos_jax.models import config as model_config
from kosmos_jax.models import kosmos2
from kosmos_jax.models.connector_extensions import instruction_bag

TINY = model_config.TINY
READS = TINY.replace(connector_instruction=True, latent_query_num=64)
GRID = TINY.vision.image_size // TINY.vision.patch_size


def test_the_bag_is_the_mean_embedding_of_the_tokens_between_image_and_answer():
    table = jnp.arange(10 * 3, dtype=jnp.float32).reshape(10, 3)
    # <s> <image> slot slot </image> w w w | answer ; a left-padded prompt ; a row without instruction
    ids = jnp.asarray([[0, 9, 5, 5, 8, 1, 2, 3, 4, 4],
                       [7, 7, 0, 9, 5, 5, 8, 6, 2, 7],
                       [0, 9, 5, 5, 8, 4, 4, 4, 4, 4]])
    mask = jnp.asarray([[1] * 10, [0, 0] + [1] * 8, [1] * 10], bool)
    image_mask = jnp.asarray([[0, 0, 1, 1, 0, 0, 0, 0, 0, 0], [0, 0, 0, 0, 1, 1, 0, 0, 0, 0],
                              [0, 0, 1, 1, 0, 0, 0, 0, 0, 0]], bool)
    answer = jnp.asarray([[0] * 8 + [1, 1], [0] * 10, [0] * 5 + [1] * 5], bool)
    bag = np.asarray(instruction_bag(table, ids, mask, image_mask, answer))
    unit_rms = lambda x: x / np.sqrt(np.mean(x ** 2))
    np.testing.assert_allclose(bag[0], unit_rms(np.asarray(table)[[1, 2, 3]].mean(axis=0)), rtol=1e-6)
    np.testing.assert_allclose(bag[1], unit_rms(np.asarray(table)[[6, 2, 7]].mean(axis=0)), rtol=1e-6)  # a prompt
    np.testing.assert_array_equal(bag[2], 0.0)  # NON: nothing between </image> and the answer


def _features(batch=2):
    return jax.random.normal(jax.random.key(0), (batch, 1 + GRID * GRID, TINY.vision.hidden_size))


@pytest.mark.slow  # builds the tiny model three times: kept out of the fast suite, at 14 min 38 s on 2 cores
def test_the_instruction_starts_with_no_effect_and_a_connector_that_reads_it_refuses_to_go_without():
    model = kosmos2.build(READS)
    connector = model.image_to_text_projection
    bag = jax.random.normal(jax.random.key(1), (2, TINY.text.embed_dim))
    # zero-initialised: at the start the slots are those of the same connector without the instruction
    plain = kosmos2.build(READS.replace(connector_instruction=False)).image_to_text_projection
    np.testing.assert_array_equal(connector(_features(), bag), plain(_features()))
    connector.instruction.kernel[...] = jnp.full(connector.instruction.kernel.shape, 0.1)
    assert np.abs(connector(_features(), bag) - connector(_features(), -bag)).max() > 1e-3
    with pytest.raises(ValueError, match="reads the instruction"):
        connector(_features())
    ids = jnp.zeros((1, 70), jnp.int32)
    with pytest.raises(ValueError, match="give image_embeds"):
        model(ids, jnp.ones_like(ids, bool), jnp.zeros_like(ids, bool), pixels=jnp.zeros((1, 30, 30, 3)))
    assert kosmos2.build(TINY).instruction_bag(ids, jnp.ones_like(ids, bool), jnp.zeros_like(ids, bool)) is None


def test_the_option_is_an_extension_written_only_when_set_and_read_back():
    config = READS.replace(connector_grid_code=2.0)
    extended = config.to_extended_hf_dict()
    assert extended[model_config.EXTENSIONS_KEY] == {"connector_grid_code": 2.0, "connector_instruction": True}
    assert model_config.Kosmos2Config.from_hf_dict(extended).connector_instruction is True
    only_grid = TINY.replace(connector_grid_code=2.0).to_extended_hf_dict()[model_config.EXTENSIONS_KEY]
    assert only_grid == {"connector_grid_code": 2.0}
    assert model_config.Kosmos2Config.from_hf_dict(TINY.replace(connector_grid_code=2.0).to_extended_hf_dict()) \
        .connector_instruction is False


def test_a_start_with_another_connector_is_refused_by_name():
    from kosmos_jax.train.run_start import check_same_model

    with pytest.raises(ValueError, match="connector_instruction False there, True here"):
        check_same_model(TINY, TINY.replace(connector_instruction=True), "runs/start")
    check_same_model(READS, READS, "runs/start")


def test_kosmos2s_connector_is_built_without_the_options_and_reads_no_instruction():
    from flax import nnx

    from kosmos_jax.models.connector import ImageToTextProjection
    from kosmos_jax.models.connector_extensions import ExtendedProjection, projection

    plain = projection(TINY, nnx.Rngs(0))
    assert type(plain) is ImageToTextProjection
    with pytest.raises(ValueError, match="reads no instruction"):
        plain(_features(), jnp.ones((2, TINY.text.embed_dim)))
    paths = lambda module: {path for path, _ in nnx.to_flat_state(nnx.state(module, nnx.Param))}
    for option in (dict(connector_grid_code=2.0), dict(connector_instruction=True)):
        extended = projection(TINY.replace(**option), nnx.Rngs(0))
        assert type(extended) is ExtendedProjection
        added = {path[0] for path in paths(extended) - paths(plain)}
        assert added == ({"instruction"} if "connector_instruction" in option else set())
        assert paths(plain) <= paths(extended)  # KOSMOS-2's weights keep their paths
