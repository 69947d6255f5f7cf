"""The training state (parameters, optimiser state, step, other model state) and its placement on a mesh.

Parameters are the model's `nnx.Param` variables as an nnx.State; optax's moments copy that tree,
variables and their `logical_axes` included, so every moment is sharded like its parameter
through the one rules table (models/sharding.py); optax's scalars (counts) are replicated.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from flax import nnx
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.kosmos2 import abstract_model, split_model
from kosmos_jax.models.sharding import param_shardings


class TrainState(NamedTuple):
    params: nnx.State  # the model's nnx.Param variables
    opt_state: optax.OptState
    step: jax.Array  # int32 scalar: updates applied so far
    model_state: Any = ()  # variables carried between steps besides parameters (BatchNorm statistics); KOSMOS: none


def _is_variable(x) -> bool:
    return isinstance(x, nnx.Variable)


def _fresh_state(params: nnx.State, tx: optax.GradientTransformation) -> TrainState:
    return TrainState(params, tx.init(params), jnp.zeros((), jnp.int32))


def state_shardings(state: TrainState, mesh: Mesh) -> TrainState:
    """A NamedSharding for every variable and array of a (concrete or abstract) TrainState: a prefix tree."""
    replicated = NamedSharding(mesh, PartitionSpec())

    def one(x):
        return param_shardings(x, mesh) if _is_variable(x) else replicated

    return jax.tree.map(one, state, is_leaf=_is_variable)


def abstract_train_state(model_config: Kosmos2Config, tx: optax.GradientTransformation, mesh: Mesh) -> TrainState:
    """The TrainState as ShapeDtypeStructs carrying their shardings (restore targets, AOT compilation)."""
    _, params, _ = split_model(abstract_model(model_config))
    abstract = jax.eval_shape(lambda p: _fresh_state(p, tx), params)

    def with_sharding(sharding, subtree):
        return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=sharding), subtree)

    return jax.tree.map(with_sharding, state_shardings(abstract, mesh), abstract,
                        is_leaf=lambda x: isinstance(x, NamedSharding))


def init_train_state(params: nnx.State, tx: optax.GradientTransformation, mesh: Mesh) -> TrainState:
    """Step 0 from given parameters (fresh or imported), placed on `mesh` as the train step expects."""
    abstract = jax.eval_shape(lambda p: _fresh_state(p, tx), params)
    shardings = state_shardings(abstract, mesh)
    return jax.jit(lambda p: _fresh_state(p, tx), out_shardings=shardings)(params)
