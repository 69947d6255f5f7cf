"""Checkpoints of a run with orbax: WORKDIR/checkpoints/STEP holds the train state, the data
iterator's state and the run's description (config, data identity, RNG) as JSON.

The trainer saves and restores all of it. Readers that only use the model (evaluation, prediction,
export) restore the parameters alone: orbax reads the `params` subtree of the state item
(PyTreeRestore's partial restore) and never reads, nor allocates, the optimiser's moments.

The train state goes to orbax as a nested dict of arrays keyed by its tree paths, so a restore
needs only a target of the same paths (ShapeDtypeStructs with the shardings wanted): a checkpoint
written on one mesh restores onto any other. Saves are asynchronous; orbax writes each step under
a temporary name and renames it when complete, so a run killed mid-save resumes from the newest
complete step.
"""

from __future__ import annotations

import pathlib

import jax
import orbax.checkpoint as ocp

from kosmos_jax.workdir.files import RunError

ITEMS = ("state", "data", "run")


def _key_name(key) -> str:
    for attribute in ("name", "key", "idx"):
        if hasattr(key, attribute):
            return str(getattr(key, attribute))
    return str(key)


def to_nested(tree) -> dict:
    """{path part: {...: array}} of every leaf of `tree`."""
    nested: dict = {}
    for path, leaf in jax.tree_util.tree_flatten_with_path(tree)[0]:
        names = [_key_name(k) for k in path] or ["value"]
        node = nested
        for name in names[:-1]:
            node = node.setdefault(name, {})
        if names[-1] in node:
            raise ValueError(f"two leaves of the train state share the path {'/'.join(names)}")
        node[names[-1]] = leaf
    return nested


def from_nested(nested: dict, like):
    """A tree shaped like `like` whose leaves are read from `nested` by their paths."""
    paths, treedef = jax.tree_util.tree_flatten_with_path(like)
    leaves = []
    for path, _ in paths:
        node = nested
        for name in [_key_name(k) for k in path] or ["value"]:
            node = node[name]
        leaves.append(node)
    return jax.tree_util.tree_unflatten(treedef, leaves)


class Checkpoints:
    """The checkpoints of one workdir; as a context manager, closed (pending saves finished) on leaving."""

    def __init__(self, workdir, keep: int = 3, asynchronous: bool = True):
        self.directory = pathlib.Path(workdir).resolve() / "checkpoints"
        options = ocp.CheckpointManagerOptions(max_to_keep=keep, enable_async_checkpointing=asynchronous, create=True)
        self.manager = ocp.CheckpointManager(self.directory, options=options, item_names=ITEMS)

    def latest_step(self) -> int | None:
        return self.manager.latest_step()

    def all_steps(self) -> list[int]:
        return list(self.manager.all_steps())

    def save(self, step: int, state, data_state: dict, run: dict) -> None:
        self.manager.save(step, args=ocp.args.Composite(
            state=ocp.args.StandardSave(to_nested(state)),
            data=ocp.args.JsonSave(data_state),
            run=ocp.args.JsonSave(run)), force=True)

    def restore(self, step: int, abstract_state):
        """(state, data iterator state, run description) of `step`, the state placed as
        `abstract_state`'s shardings say."""
        restored = self.manager.restore(step, args=ocp.args.Composite(
            state=ocp.args.StandardRestore(to_nested(abstract_state)),
            data=ocp.args.JsonRestore(),
            run=ocp.args.JsonRestore()))
        return from_nested(restored["state"], abstract_state), restored["data"], restored["run"]

    def restore_fields(self, step: int, abstract_fields: dict) -> dict:
        """{field: tree} of the train state's top-level fields named in `abstract_fields` (e.g.
        {"params": ...}: a tree of ShapeDtypeStructs with the shardings wanted); the state's other
        fields (the optimiser's moments, the step) are neither read nor allocated."""
        target = to_nested(abstract_fields)
        restored = self.manager.restore(step, args=ocp.args.Composite(state=ocp.args.PyTreeRestore(
            target, restore_args=ocp.checkpoint_utils.construct_restore_args(target), partial_restore=True)))
        # a field without arrays (a model without BatchNorm's empty model_state) is not in the checkpoint
        return {name: from_nested(restored["state"].get(name, {}), like) for name, like in abstract_fields.items()}

    def run_info(self, step: int) -> dict:
        """The run description stored with `step`, without reading the arrays."""
        return self.manager.restore(step, args=ocp.args.Composite(run=ocp.args.JsonRestore()))["run"]

    def wait(self) -> None:
        self.manager.wait_until_finished()

    def close(self) -> None:
        self.manager.wait_until_finished()
        self.manager.close()

    def __enter__(self) -> Checkpoints:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def checkpoint_steps(workdir) -> list[int]:
    """The complete checkpoints' steps of `workdir`, oldest first."""
    workdir = pathlib.Path(workdir)
    if not (workdir / "checkpoints").is_dir():
        return []
    with Checkpoints(workdir, asynchronous=False) as checkpoints:
        return sorted(checkpoints.all_steps())


def chosen_step(workdir, step: int | None) -> int:
    """`step` (None: the newest) if the workdir holds its checkpoint, else a RunError saying what it holds."""
    steps = checkpoint_steps(workdir)
    if not steps:
        raise RunError(f"{workdir} holds no checkpoint (checkpoints/ is empty or missing): train first")
    step = steps[-1] if step is None else step
    if step not in steps:
        raise RunError(f"{workdir} has no checkpoint of step {step}; it has {steps}")
    return step


def restore_params(workdir, step: int, abstract_params):
    """The parameters of checkpoint `step` of `workdir`, placed as `abstract_params`' shardings say."""
    with Checkpoints(workdir, asynchronous=False) as checkpoints:
        return checkpoints.restore_fields(step, {"params": abstract_params})["params"]
