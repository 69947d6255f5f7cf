"""The device mesh (data, fsdp, tensor) that a model's parameters and activations are placed on.

Axes are Auto (GSPMD propagates shardings from the parameters, the batch and the model's
`constrain` calls), not jax.make_mesh's default Explicit, which would need every op typed.
Training, scoring and prediction all build their mesh here.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
from jax.sharding import AxisType, Mesh

from kosmos_jax.models.sharding import MESH_AXES


def mesh_shape(sizes: Sequence[int], device_count: int) -> tuple[int, ...]:
    """Axis sizes with one -1 replaced by the devices left; the product must be the device count."""
    if sum(size == -1 for size in sizes) > 1 or any(size == 0 or size < -1 for size in sizes):
        raise ValueError(f"mesh sizes {tuple(sizes)}: each positive, at most one -1")
    known = math.prod(size for size in sizes if size != -1)
    if device_count % known:
        raise ValueError(f"mesh sizes {tuple(sizes)} do not divide {device_count} devices")
    shape = tuple(device_count // known if size == -1 else size for size in sizes)
    if math.prod(shape) != device_count:
        raise ValueError(f"mesh {dict(zip(MESH_AXES, shape))} uses {math.prod(shape)} of {device_count} devices")
    return shape


def make_mesh(data: int = 1, fsdp: int = -1, tensor: int = 1, devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A (data, fsdp, tensor) mesh over `devices` (default: all devices of all processes)."""
    devices = list(jax.devices() if devices is None else devices)
    shape = mesh_shape((data, fsdp, tensor), len(devices))
    return jax.make_mesh(shape, MESH_AXES, axis_types=(AxisType.Auto,) * len(MESH_AXES), devices=devices)
