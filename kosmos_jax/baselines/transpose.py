"""A transposed convolution computed as one ordinary convolution and a pixel shuffle.

PyTorch's ConvTranspose2d semantics, in NHWC: with kernel K [k, k, in, out], stride s and padding p,

    y[o] = sum over i, k with o = s * i + k - p  of  x[i] K[k]          (per axis; y has s * n rows)

(output padding s + 2p - k, so the output is exactly s times the input). Output row o = s * m + a
(phase a) reads input rows m + d for the kernel taps k = a + p - s * d, so each phase is an ordinary
convolution over a small window of input rows: all phases together are ONE convolution at the
input's resolution with s * s * out channels, whose kernel is gathered from K (zeros where a phase
has no tap), followed by depth-to-space. Same function, same parameters as the transposed
convolution; but XLA on CPU takes 20-30x longer for the gradient of a stride-2
`lax.conv_transpose` (measured: 8-12 s against under 0.5 s for GR-ConvNet's two up-sampling layers
at batch 8 on this 2-core machine), which made GR-ConvNet's training step take 36 s.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx


def phase_taps(kernel: int, stride: int, padding: int) -> tuple[np.ndarray, int, int]:
    """(index [stride, window] of the kernel tap each phase applies at each window row, -1 for none;
    the window's first input row offset d_min; its last d_max), for one axis."""
    taps = {(a, (a + padding - k) // stride): k for a in range(stride) for k in range(kernel)
            if (a + padding - k) % stride == 0}
    offsets = [d for _, d in taps]
    low, high = min(offsets), max(offsets)
    index = np.full((stride, high - low + 1), -1, np.int32)
    for (a, d), k in taps.items():
        index[a, d - low] = k
    return index, low, high


class ConvTranspose(nnx.Module):
    """[B, H, W, in] -> [B, stride * H, stride * W, out]; kernel [k, k, in, out], bias [out]."""

    def __init__(self, in_features: int, out_features: int, kernel: int, stride: int = 1,
                 padding: int | None = None, *, kernel_init, kernel_metadata=None, bias_metadata=None,
                 rngs: nnx.Rngs):
        self.stride = stride
        self.padding = (kernel - stride + 1) // 2 if padding is None else padding
        if stride + 2 * self.padding - kernel < 0:
            raise ValueError(f"kernel {kernel}, stride {stride}, padding {self.padding}: the output would be "
                             f"shorter than {stride} x the input")
        self.kernel = nnx.Param(kernel_init(rngs.params(), (kernel, kernel, in_features, out_features)),
                                **(kernel_metadata or {}))
        self.bias = nnx.Param(jnp.zeros((out_features,), jnp.float32), **(bias_metadata or {}))

    def __call__(self, x: jax.Array) -> jax.Array:
        k, _, c_in, c_out = self.kernel.shape
        s = self.stride
        index, low, high = phase_taps(k, s, self.padding)
        valid = index >= 0
        rows = np.where(valid, index, 0)
        # [window, window, phase_r, phase_c, in, out]: K[rows[a, t], rows[b, u]] where both taps exist
        gathered = self.kernel[...][rows.T[:, None, :, None], rows.T[None, :, None, :]]
        mask = (valid.T[:, None, :, None] & valid.T[None, :, None, :]).astype(gathered.dtype)
        window = index.shape[1]
        weights = (gathered * mask[..., None, None]).transpose(0, 1, 4, 2, 3, 5)
        weights = weights.reshape(window, window, c_in, s * s * c_out)
        # output phase rows m read input rows m + low .. m + high: pad -low before, high after
        pad = (max(-low, 0), max(high, 0))
        y = jax.lax.conv_general_dilated(x, weights.astype(x.dtype), (1, 1), (pad, pad),
                                         dimension_numbers=("NHWC", "HWIO", "NHWC"))
        start = max(low, 0)  # a window entirely after row m (low > 0) starts further in
        height, width = x.shape[1:3]
        y = y[:, start:start + height, start:start + width]
        batch = x.shape[0]
        y = y.reshape(batch, height, width, s, s, c_out).transpose(0, 1, 3, 2, 4, 5)
        return y.reshape(batch, s * height, s * width, c_out) + self.bias[...].astype(y.dtype)
