"""The convolution layers both baselines are built from, and their four output maps.

Kernels are drawn Xavier-uniform (as both papers' networks are initialised) and carry logical axis
names (kosmos_jax.models.sharding): the kernel's window and input channels are "patch" axes and its
output channels unnamed, so the one rules table keeps these small networks replicated on any mesh.
Inputs and outputs are NHWC.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
from flax import nnx

from kosmos_jax.baselines.transpose import ConvTranspose

KERNEL_AXES = {"logical_axes": ("patch", "patch", "patch", None)}
VECTOR_AXES = {"logical_axes": ("norm",)}
xavier = nnx.initializers.xavier_uniform()
MODES = {"depth": 1, "rgb": 3, "rgbd": 4}  # input channels of each input mode


class GraspMaps(NamedTuple):
    """The four pixel-wise maps of a generative grasp network, each [B, H, W] float32."""

    quality: jax.Array
    cos: jax.Array  # cos 2 theta
    sin: jax.Array  # sin 2 theta
    width: jax.Array  # opening / width scale


def conv(in_features: int, out_features: int, kernel: int, *, rngs: nnx.Rngs, stride: int = 1,
         dilation: int = 1) -> nnx.Conv:
    """A convolution with "SAME" padding: stride s maps H to ceil(H / s)."""
    return nnx.Conv(in_features, out_features, (kernel, kernel), strides=stride, kernel_dilation=dilation,
                    padding="SAME", kernel_init=xavier, kernel_metadata=KERNEL_AXES, bias_metadata=VECTOR_AXES,
                    rngs=rngs)


def conv_transpose(in_features: int, out_features: int, kernel: int, *, rngs: nnx.Rngs,
                   stride: int = 1) -> ConvTranspose:
    """A transposed convolution (PyTorch's, padding (kernel - stride + 1) // 2) mapping H to stride * H."""
    return ConvTranspose(in_features, out_features, kernel, stride, kernel_init=xavier,
                         kernel_metadata=KERNEL_AXES, bias_metadata=VECTOR_AXES, rngs=rngs)


def batch_norm(features: int, *, rngs: nnx.Rngs) -> nnx.BatchNorm:
    """BatchNorm with PyTorch's defaults (running averages updated by 0.1 a step, eps 1e-5)."""
    return nnx.BatchNorm(features, momentum=0.9, epsilon=1e-5, scale_metadata=VECTOR_AXES,
                         bias_metadata=VECTOR_AXES, rngs=rngs)


class Heads(nnx.Module):
    """The four output heads (quality, cos 2 theta, sin 2 theta, width) over shared features: one
    convolution with four output channels, the same function as four one-channel convolutions and
    one pass over the features instead of four."""

    def __init__(self, features: int, kernel: int, *, rngs: nnx.Rngs):
        self.maps = conv(features, 4, kernel, rngs=rngs)

    def __call__(self, x: jax.Array) -> GraspMaps:
        y = self.maps(x)
        return GraspMaps(*(y[..., i] for i in range(4)))


def input_channels(mode: str) -> int:
    """Channels of an input mode: depth 1, rgb 3, rgbd 4 (R, G, B, D)."""
    if mode not in MODES:
        raise ValueError(f"input mode {mode!r} must be one of {tuple(MODES)}")
    return MODES[mode]

