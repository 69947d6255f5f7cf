"""Where the trainer's batches and scalars live on the device mesh (models/mesh.py builds the mesh)."""

from __future__ import annotations

from jax.sharding import Mesh, NamedSharding, PartitionSpec

from kosmos_jax.models.sharding import mesh_axes_for


def batch_sharding(mesh: Mesh) -> NamedSharding:
    """Every batch array: its leading (example) axis over the data-parallel axes (data, fsdp)."""
    return NamedSharding(mesh, mesh_axes_for(("batch",), mesh_axis_names=mesh.axis_names))


def replicated(mesh: Mesh) -> NamedSharding:
    return NamedSharding(mesh, PartitionSpec())
