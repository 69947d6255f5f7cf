"""Logical axis names and THE table that maps them to mesh axes (data, fsdp, tensor).

Every parameter carries logical names in its `logical_axes` metadata (not flax's `out_sharding`,
which would shard eagerly at creation and needs a mesh) and every large activation
passes through `constrain`; only `LOGICAL_AXIS_RULES` says which mesh axis each name lands on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
from flax import nnx
from jax.sharding import NamedSharding, PartitionSpec

MESH_AXES = ("data", "fsdp", "tensor")

# logical name -> mesh axis (or axes, or None = replicated)
LOGICAL_AXIS_RULES: tuple[tuple[str, str | tuple[str, ...] | None], ...] = (
    ("batch", ("data", "fsdp")),  # activations: batch over data-parallel and fsdp devices
    ("length", None),
    ("embed", "fsdp"),  # parameters: model width sharded fully (ZeRO-3 style)
    ("mlp", "tensor"),
    ("heads", "tensor"),  # q/k/v output features and out_proj input features
    ("kv", None),  # per-head features of attention outputs and the KV cache
    ("vocab", "tensor"),
    ("norm", None),  # LayerNorm scales and biases: small, replicated
    ("patch", None),  # patch-conv kernel height, width, channels
    ("positions", None),
    ("latents", None),
    ("layers", None),  # the leading axis of stacked (scanned) blocks: every device holds every layer's slice
    ("act_embed", None),  # activations' feature axis: replicated between tensor-parallel ops
    ("act_mlp", "tensor"),
    ("act_heads", "tensor"),
    ("act_vocab", "tensor"),
)


def mesh_axes_for(logical: Sequence[str | None], rules=LOGICAL_AXIS_RULES, mesh_axis_names=MESH_AXES,
                  shape: Sequence[int] | None = None, mesh_axis_sizes: dict[str, int] | None = None) -> PartitionSpec:
    """PartitionSpec over mesh axes for a tuple of logical names; each mesh axis used at most once.

    Given `shape` and `mesh_axis_sizes`, a dimension the mesh axes do not divide (KOSMOS-2's vocabulary
    of 65037, odd test sizes) is left replicated instead of failing.
    """
    table = dict(rules)
    used: set[str] = set()
    spec = []
    for dim, name in enumerate(logical):
        if name is None:
            spec.append(None)
            continue
        if name not in table:
            raise KeyError(f"logical axis {name!r} has no rule in LOGICAL_AXIS_RULES")
        target = table[name]
        axes = (target,) if isinstance(target, str) else tuple(target or ())
        axes = tuple(a for a in axes if a in mesh_axis_names and a not in used)
        if shape is not None and mesh_axis_sizes is not None and shape[dim] % math.prod(mesh_axis_sizes[a] for a in axes):
            axes = ()
        used.update(axes)
        spec.append(None if not axes else axes[0] if len(axes) == 1 else axes)
    return PartitionSpec(*spec)


def constrain(x: jax.Array, logical: Sequence[str | None]) -> jax.Array:
    """with_sharding_constraint by logical names under the current mesh; a no-op without one."""
    mesh = jax.sharding.get_abstract_mesh()
    if mesh.empty:
        return x
    spec = mesh_axes_for(logical, mesh_axis_names=mesh.axis_names, shape=x.shape, mesh_axis_sizes=dict(mesh.shape))
    return jax.lax.with_sharding_constraint(x, spec)


def logical(initializer, axes: tuple[str | None, ...]):
    """An initializer whose Param records its logical axis names."""
    return nnx.with_metadata(initializer, logical_axes=tuple(axes))


def logical_specs(state: nnx.State) -> nnx.State:
    """The logical-name PartitionSpec of every variable (empty spec = replicated when unnamed)."""

    def one(var):
        return PartitionSpec(*var.get_metadata().get("logical_axes", ()))

    return jax.tree.map(one, state, is_leaf=lambda x: isinstance(x, nnx.Variable))


def param_shardings(state: nnx.State, mesh: jax.sharding.Mesh, rules=LOGICAL_AXIS_RULES) -> nnx.State:
    """NamedSharding of every variable in `state` on `mesh`, through the rules table."""

    def one(var):
        names = var.get_metadata().get("logical_axes", ())
        return NamedSharding(mesh, mesh_axes_for(names, rules, mesh.axis_names, var.shape, dict(mesh.shape)))

    return jax.tree.map(one, state, is_leaf=lambda x: isinstance(x, nnx.Variable))
