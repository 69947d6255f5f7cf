"""A baseline as a "model family": the pure functions a trainer and an evaluator need, nothing else.

    family = make_family(BaselineConfig(network="grconvnet", mode="rgbd"))
    graphdef, params, rest = family.init(seed)                  # rest: BatchNorm running statistics
    (loss_sum, (sums, rest)), grads = jax.value_and_grad(family.loss_sums, has_aux=True)(
        params, rest, batch, key, True)                         # batch: inputs.BATCH_KEYS
    grasps = family.predict(params, rest, batch["image"])       # [B, 5] (x, y, w, h, theta)
    grasps = family.predictor("public")(params, rest, images)   # the public code's detection, NaN: none
    grasps = predict_views(family, params, rest, views)         # every view of an inputs.ViewArrays

`loss_sums` returns the loss SUMMED over the batch's images, and `sums` holds "loss_sum", "count"
(images), and each map's summed loss ("quality", "cos", "sin", "width"), so microbatches add up and
the trainer divides once by the global count: the mean is then the published batch loss. Targets
are drawn from the batch's grasps inside the loss (targets.grasp_maps), so a batch is just images,
grasps and mask. In training mode BatchNorm normalises with the batch's statistics and the returned
`rest` holds the updated running averages (GR-ConvNet; GG-CNN2 has none, its `rest` is empty); in
evaluation mode (train=False) the running averages are used and `rest` comes back unchanged.
`key` is unused (neither network has dropout) and kept so every family has one signature. A batch
with "rows" (inputs.eval_batches) counts only rows >= 0, so a padded last batch adds nothing.
BatchNorm statistics of a padded batch include the padding, so pad only in evaluation.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from kosmos_jax.baselines.ggcnn2 import GGCNN2
from kosmos_jax.baselines.grconvnet import GRConvNet
from kosmos_jax.baselines.inputs import ViewArrays, eval_batches
from kosmos_jax.baselines.layers import input_channels
from kosmos_jax.baselines.losses import NETWORK_LOSS, map_losses
from kosmos_jax.baselines.predict import predict_grasps
from kosmos_jax.baselines.public_detect import detect_grasps
from kosmos_jax.sources.splits import PUBLIC
from kosmos_jax.baselines.targets import WIDTH_SCALE, grasp_maps

NETWORKS = ("grconvnet", "ggcnn2")


@dataclasses.dataclass(frozen=True)
class BaselineConfig:
    network: str = "grconvnet"
    mode: str = "rgbd"  # depth, rgb or rgbd
    channels: int = 32  # GR-ConvNet's width c (GG-CNN2 has its fixed filters)
    loss: str | None = None  # None: the network's published loss
    width_scale: float = WIDTH_SCALE

    def __post_init__(self):
        if self.network not in NETWORKS:
            raise ValueError(f"network {self.network!r} must be one of {NETWORKS}")
        input_channels(self.mode)

    @property
    def loss_kind(self) -> str:
        return self.loss or NETWORK_LOSS[self.network]


def build(config: BaselineConfig, seed: int) -> nnx.Module:
    rngs = nnx.Rngs(seed)
    if config.network == "grconvnet":
        return GRConvNet(input_channels(config.mode), config.channels, rngs=rngs)
    return GGCNN2(input_channels(config.mode), rngs=rngs)


@dataclasses.dataclass(frozen=True)
class Family:
    """The pure functions of one baseline configuration (see the module docstring)."""

    config: BaselineConfig
    graphdef: Any
    init: Callable  # seed -> (graphdef, params, rest)
    loss_sums: Callable  # (params, rest, batch, key, train) -> (loss_sum, (sums, rest))
    predict: Callable  # (params, rest, images) -> [B, 5]
    detect_public: Callable  # (params, rest, images) -> [B, 5], NaN rows where the public code finds no peak

    def predictor(self, protocol: str) -> Callable:
        """The grasps a protocol scores: the public code's detection under "public", else `predict`."""
        return self.detect_public if protocol == PUBLIC else self.predict


def make_family(config: BaselineConfig) -> Family:
    graphdef, _, _ = nnx.split(nnx.eval_shape(lambda: build(config, 0)), nnx.Param, ...)

    def init(seed: int):
        return nnx.split(build(config, seed), nnx.Param, ...)

    def model(params, rest, train: bool):
        # copy: `rest` may come from an outer trace (jit around grad) and BatchNorm writes to it
        merged = nnx.merge(graphdef, params, rest, copy=True)
        return merged if train else nnx.view(merged, use_running_average=True, raise_if_not_found=False)

    def loss_sums(params, rest, batch, key, train: bool = True):
        del key
        network = model(params, rest, train)
        images = batch["image"]
        predicted = network(images)
        target = grasp_maps(batch["grasps"], batch["mask"], images.shape[1:3], config.width_scale)
        per_map = map_losses(predicted, target, config.loss_kind)
        counted = batch["rows"] >= 0 if "rows" in batch else jnp.ones(images.shape[:1], bool)
        sums = {name: jnp.sum(jnp.where(counted, value, 0.0))
                for name, value in zip(("quality", "cos", "sin", "width"), per_map)}
        loss_sum = sum(sums.values())
        sums.update(loss_sum=loss_sum, count=jnp.sum(counted, dtype=jnp.int32))
        new_rest = nnx.split(network, nnx.Param, ...)[2] if train else rest
        return loss_sum, (sums, new_rest)

    def predict(params, rest, images):
        grasps, _ = predict_grasps(model(params, rest, False)(images), width_scale=config.width_scale)
        return grasps

    def detect_public(params, rest, images):
        grasps, _ = detect_grasps(model(params, rest, False)(images), width_scale=config.width_scale)
        return grasps

    return Family(config, graphdef, init, loss_sums, predict, detect_public)


def predict_views(family: Family, params, rest, views: ViewArrays, batch_size: int = 8,
                  protocol: str = "honest") -> np.ndarray:
    """[V, 5] grasps of every view under `protocol` (family.predictor), in the views' order (one
    compiled batch shape; padding dropped)."""
    predict = jax.jit(family.predictor(protocol))
    parts = []
    for batch in eval_batches(views, batch_size):
        grasps = np.asarray(predict(params, rest, jnp.asarray(batch["image"])))
        parts.append(grasps[batch["rows"] >= 0])
    return np.concatenate(parts)
