"""The model a run's config names: its `model` section and the tokenizer's vocabulary give a
Kosmos2Config (the trainer builds it; readers of a workdir rebuild it from run.json)."""

from __future__ import annotations

import dataclasses

import ml_collections

from kosmos_jax.models import config as model_configs
from kosmos_jax.text import tokens as special


def model_config(model: ml_collections.ConfigDict, vocab_size: int) -> model_configs.Kosmos2Config:
    """The Kosmos2Config a config's `model` section names, with the tokenizer's vocabulary."""
    base = model_configs.get_config(model.size)
    given = lambda section: {name: value for name, value in section.to_dict().items() if value is not None}
    vision = dataclasses.replace(base.vision, **given(model.vision))
    text = dataclasses.replace(base.text, **{**given(model.text), "vocab_size": vocab_size})
    if model.latent_query_num != special.IMAGE_SLOTS:
        raise ValueError(f"model.latent_query_num={model.latent_query_num}: the prompt has {special.IMAGE_SLOTS} image slots")
    # .get: the configs stored by runs before the connector options existed (evaluate reads them) lack them
    return base.replace(vision=vision, text=text, latent_query_num=model.latent_query_num,
                        compute_dtype=model.compute_dtype, magneto_init=model.magneto_init, remat=model.remat,
                        scan_layers=model.scan_layers, connector_dense_std=model.get("connector_dense_std"),
                        connector_grid_code=model.get("connector_grid_code", 0.0),
                        connector_instruction=model.get("connector_instruction", False),
                        attention=model.get("attention", "einsum"), remat_policy=model.get("remat_policy", "full"),
                        dropout_mask_bits=model.get("dropout_mask_bits", 32))
