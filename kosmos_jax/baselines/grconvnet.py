"""GR-ConvNet (Kumra, Joshi and Sahin, "Antipodal Robotic Grasping using Generative Residual
Convolutional Neural Network", IROS 2020), from the paper's description, in flax.nnx.

    net = GRConvNet(input_channels(mode), channels=32, rngs=nnx.Rngs(0))
    maps = net(images)          # images [B, H, W, C] -> GraspMaps, each [B, H, W]

Three convolutions bring the image down (9x9 stride 1, then 4x4 stride 2 twice: C -> c -> 2c -> 4c
channels at H/4), five residual blocks (two 3x3 convolutions with BatchNorm, ReLU between them, the
input added back) work at H/4, three transposed convolutions bring it back up (4x4 stride 2 twice,
then 9x9 stride 1: 4c -> 2c -> c -> c), and four 2x2 convolutions give the quality, cos 2 theta,
sin 2 theta and width maps. Every down or up layer but the last 9x9 has BatchNorm and ReLU; the
heads are linear. c = 32 in the paper; H must be a multiple of 4 (224 here).

Differences from the public implementation, which change no result: "SAME" padding for the
convolutions and transposed convolutions padded so that stride 2 exactly doubles the size (PyTorch's
ConvTranspose2d with padding 1, no output padding; transpose.py), so a 224 input gives 224 maps
without the odd intermediate sizes (113, 225) the public padding makes and the 2x2 heads' valid
convolution then trims; no dropout before the heads (an option of the public code). Trained with
the smooth L1 loss (losses.py).
"""

from __future__ import annotations

import jax
from flax import nnx

from kosmos_jax.baselines.layers import GraspMaps, Heads, batch_norm, conv, conv_transpose

RESIDUAL_BLOCKS = 5


class ResidualBlock(nnx.Module):
    """x + BN(conv3x3(ReLU(BN(conv3x3(x)))))."""

    def __init__(self, features: int, *, rngs: nnx.Rngs):
        self.conv1 = conv(features, features, 3, rngs=rngs)
        self.bn1 = batch_norm(features, rngs=rngs)
        self.conv2 = conv(features, features, 3, rngs=rngs)
        self.bn2 = batch_norm(features, rngs=rngs)

    def __call__(self, x: jax.Array) -> jax.Array:
        y = nnx.relu(self.bn1(self.conv1(x)))
        return x + self.bn2(self.conv2(y))


class GRConvNet(nnx.Module):
    """The generative residual network: [B, H, W, in_channels] -> GraspMaps [B, H, W] x 4."""

    def __init__(self, in_channels: int, channels: int = 32, *, rngs: nnx.Rngs):
        c = channels
        self.conv1 = conv(in_channels, c, 9, rngs=rngs)
        self.bn1 = batch_norm(c, rngs=rngs)
        self.conv2 = conv(c, 2 * c, 4, stride=2, rngs=rngs)
        self.bn2 = batch_norm(2 * c, rngs=rngs)
        self.conv3 = conv(2 * c, 4 * c, 4, stride=2, rngs=rngs)
        self.bn3 = batch_norm(4 * c, rngs=rngs)
        self.residual = nnx.List([ResidualBlock(4 * c, rngs=rngs) for _ in range(RESIDUAL_BLOCKS)])
        self.up1 = conv_transpose(4 * c, 2 * c, 4, stride=2, rngs=rngs)
        self.bn4 = batch_norm(2 * c, rngs=rngs)
        self.up2 = conv_transpose(2 * c, c, 4, stride=2, rngs=rngs)
        self.bn5 = batch_norm(c, rngs=rngs)
        self.up3 = conv_transpose(c, c, 9, rngs=rngs)
        self.heads = Heads(c, 2, rngs=rngs)

    def __call__(self, images: jax.Array) -> GraspMaps:
        if images.shape[1] % 4 or images.shape[2] % 4:
            raise ValueError(f"GR-ConvNet needs a height and width divisible by 4, got {images.shape[1:3]}")
        x = nnx.relu(self.bn1(self.conv1(images)))
        x = nnx.relu(self.bn2(self.conv2(x)))
        x = nnx.relu(self.bn3(self.conv3(x)))
        for block in self.residual:
            x = block(x)
        x = nnx.relu(self.bn4(self.up1(x)))
        x = nnx.relu(self.bn5(self.up2(x)))
        return self.heads(self.up3(x))
