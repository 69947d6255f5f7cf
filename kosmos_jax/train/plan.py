"""The TPU memory plan of `make plan`: the `paper` config's train step on each topology, with its mesh.

    python -m kosmos_jax.train.compile --config=configs/kosmos_e.py:paper --plan [--json]

Every mesh puts the global batch (64 sequences in `paper`) over (data, fsdp). The 256 chips of a
v5e:16x16 outnumber the sequences, so that mesh shards the heads and MLPs of every block over a
`tensor` axis of 4 as well. Rematerialisation only where the step would not fit without it.
"""

from __future__ import annotations

import dataclasses

import ml_collections


@dataclasses.dataclass(frozen=True)
class PlanEntry:
    topology: str
    mesh: tuple[int, int, int]  # data, fsdp, tensor
    remat: bool = False


PLAN = (
    PlanEntry("v5e:2x2", (1, 4, 1), remat=True),
    PlanEntry("v5e:2x4", (1, 8, 1)),
    PlanEntry("v4:2x2x1", (1, 4, 1)),
    PlanEntry("v6e:2x2", (1, 4, 1)),
    PlanEntry("v5e:16x16", (4, 16, 4)),
)


def entry_config(config: ml_collections.ConfigDict, entry: PlanEntry) -> ml_collections.ConfigDict:
    """A copy of `config` with the entry's mesh and remat."""
    planned = config.copy_and_resolve_references()
    planned.mesh.data, planned.mesh.fsdp, planned.mesh.tensor = entry.mesh
    planned.model.remat = entry.remat
    return planned
