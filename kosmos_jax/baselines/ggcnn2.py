"""GG-CNN2 (Morrison, Corke and Leitner, "Learning robust, real-time, reactive robotic grasping",
IJRR 2020; GG-CNN, RSS 2018), the dilated fully-convolutional net, from the paper's description.

    net = GGCNN2(input_channels("depth"), rngs=nnx.Rngs(0))
    maps = net(images)          # images [B, H, W, C] -> GraspMaps, each [B, H, W]

Two 11x11 / 5x5 convolutions (16 filters) and a 2x2 max-pool, two 5x5 convolutions (16) and a
max-pool, two 5x5 dilated convolutions (32 filters, dilation 2 then 4) that widen the receptive
field without more pooling, two 3x3 stride-2 transposed convolutions (16 filters; PyTorch's padding
1 and output padding 1, transpose.py) back to full resolution, every layer followed by ReLU, and
four linear 1x1 heads (quality, cos 2 theta, sin 2 theta, width).
No normalisation layers. The paper's input is a 300 px depth crop; here any H, W divisible by 4 (224
views) and 1, 3 or 4 input channels. Trained with the mean squared error (losses.py).
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
from flax import nnx

from kosmos_jax.baselines.layers import GraspMaps, Heads, conv, conv_transpose

FILTERS = (16, 16, 32, 16)  # first convs, second convs, dilated convs, transposed convs
DILATIONS = (2, 4)


def max_pool(x: jax.Array) -> jax.Array:
    return nnx.max_pool(x, (2, 2), strides=(2, 2))


class GGCNN2(nnx.Module):
    """[B, H, W, in_channels] -> GraspMaps [B, H, W] x 4."""

    def __init__(self, in_channels: int = 1, filters: Sequence[int] = FILTERS,
                 dilations: Sequence[int] = DILATIONS, *, rngs: nnx.Rngs):
        f0, f1, f2, f3 = filters
        self.conv1 = conv(in_channels, f0, 11, rngs=rngs)
        self.conv2 = conv(f0, f0, 5, rngs=rngs)
        self.conv3 = conv(f0, f1, 5, rngs=rngs)
        self.conv4 = conv(f1, f1, 5, rngs=rngs)
        self.dilated1 = conv(f1, f2, 5, dilation=dilations[0], rngs=rngs)
        self.dilated2 = conv(f2, f2, 5, dilation=dilations[1], rngs=rngs)
        self.up1 = conv_transpose(f2, f3, 3, stride=2, rngs=rngs)
        self.up2 = conv_transpose(f3, f3, 3, stride=2, rngs=rngs)
        self.heads = Heads(f3, 1, rngs=rngs)

    def __call__(self, images: jax.Array) -> GraspMaps:
        if images.shape[1] % 4 or images.shape[2] % 4:
            raise ValueError(f"GG-CNN2 needs a height and width divisible by 4, got {images.shape[1:3]}")
        x = nnx.relu(self.conv1(images))
        x = max_pool(nnx.relu(self.conv2(x)))
        x = nnx.relu(self.conv3(x))
        x = max_pool(nnx.relu(self.conv4(x)))
        x = nnx.relu(self.dilated1(x))
        x = nnx.relu(self.dilated2(x))
        x = nnx.relu(self.up1(x))
        x = nnx.relu(self.up2(x))
        return self.heads(x)
