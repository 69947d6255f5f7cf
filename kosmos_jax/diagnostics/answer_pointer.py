"""Where the decoder's answer points, for runs whose image slots are the patches (train.pointing_target
"identity", train.answer_pointing_loss): whether it picked the named object even when its text does not say so.

    python -m kosmos_jax.diagnostics.answer_pointer --workdir=runs/pretrain/stream_ground [--split=validation] [--json]

For each example of the split with a target grasp: the decoder's state at the position that predicts
the first answer token scores the 64 slots' states by dot product, as `train.loss.answer_pointing_sum`
does, and the best slot is compared with the patch that holds the target grasp's centre (`cell`) and
with its 2 x 2 quadrant (`quadrant`; on a mosaic, the named photo: 25% by chance). Grouped by scene
(single photos, mosaics) and by kind.
"""

from __future__ import annotations

import json
import sys

import jax
import jax.numpy as jnp
import numpy as np
from absl import flags
from flax import nnx

from kosmos_jax import commands
from kosmos_jax.models.patch_grid import cell_index, grid_side
from kosmos_jax.models.kosmos2 import abstract_model, split_model
from kosmos_jax.train.loss import image_slot_states
from kosmos_jax.train import batches
from kosmos_jax.train.step import BATCH_KEYS, hidden_states, rng_state
from kosmos_jax.train.step import slots as slots_of
from kosmos_jax.workdir.files import RunError
from kosmos_jax.workdir.run import Run, open_run


def quadrants(cells: np.ndarray, side: int) -> np.ndarray:
    """Row-major patch indices of a side x side grid -> their 2 x 2 quadrant (0 top left .. 3 bottom right)."""
    rows, columns = np.divmod(np.asarray(cells), side)
    return 2 * (rows >= side / 2) + (columns >= side / 2)


def hit_shares(pointed: np.ndarray, targets: np.ndarray, groups: list[str], side: int) -> dict:
    """{group: {"examples", "cell", "quadrant"}}: the share of each group's examples whose pointed slot is
    the target's patch, and lies in its quadrant; "all" over every example."""
    pointed, targets = np.asarray(pointed), np.asarray(targets)
    out = {}
    for group in ["all"] + sorted(set(groups)):
        chosen = np.ones(len(groups), bool) if group == "all" else np.asarray(groups) == group
        if not chosen.any():
            continue
        out[group] = {"examples": int(chosen.sum()),
                      "cell": round(float(np.mean(pointed[chosen] == targets[chosen])), 4),
                      "quadrant": round(float(np.mean(quadrants(pointed[chosen], side) == quadrants(targets[chosen], side))), 4)}
    return out


def pointer_of(run: Run, params):
    """A jitted (batch -> [B] pointed slot) of the run's model with `params`."""
    graphdef, _, rest = split_model(abstract_model(run.model_config))
    count = run.model_config.latent_query_num

    @jax.jit
    def pointed(params, batch):
        model = nnx.view(nnx.merge(graphdef, params, rng_state(rest, jax.random.key(0))), deterministic=True)
        hidden = hidden_states(model, batch, slots_of(model, batch))
        first = jnp.argmax(batch["loss_mask"][:, 1:], axis=1)  # predicts the first answer token
        query = jnp.take_along_axis(hidden, first[:, None, None], axis=1)[:, 0]
        slot_states = image_slot_states(hidden, batch["image_mask"], count)
        return jnp.argmax(jnp.einsum("bd,bsd->bs", query, slot_states), axis=-1)

    return lambda batch: np.asarray(pointed(params, {key: jnp.asarray(batch[key]) for key in BATCH_KEYS}))


def answer_pointer(run: Run, split_name: str, step: int | None = None, batch_size: int = 32) -> dict:
    if run.config.train.get("pointing_target") != "identity":
        raise RunError(f"{run.workdir} was not trained with image slots that are the patches "
                       "(train.pointing_target='identity'); its slots have no cell to point at")
    step, params = run.params(step)
    split, pointer = run.split(split_name), pointer_of(run, params)
    side = grid_side(run.model_config.latent_query_num)
    pointed, targets, groups = [], [], []
    for batch in batches.eval_batches(split, batch_size, 0, 1):
        keep = (batch["example_index"] >= 0) & np.isfinite(batch["grasp"][:, :2]).all(-1)
        image_side = batch["image"].shape[1]
        pointed.append(pointer(batch)[keep])
        targets.append(np.asarray(cell_index(jnp.asarray(batch["grasp"][keep, :2] / image_side), side)))
        for index in batch["example_index"][keep]:
            record = split.examples[int(index)]
            scene = "multi" if len(record["photo_ids"]) > 1 else "single"
            groups.append(f"{scene} {bytes(record['kind']).decode()}")
    pointed, targets = np.concatenate(pointed), np.concatenate(targets)
    by_scene = hit_shares(pointed, targets, [g.split()[0] for g in groups], side)
    return {"step": step, "split": split_name, **by_scene, "by_kind": hit_shares(pointed, targets, groups, side)}


def define_flags(flag_values: flags.FlagValues) -> None:
    define = commands.definer(flag_values)
    define("string", "workdir", None, "the training run's folder")
    define("string", "split", "validation", "a split of the run's dataset")
    define("integer", "step", None, "checkpoint step (default: the newest)")
    define("bool", "json", False, "print the figures as one JSON line")
    flags.mark_flag_as_required("workdir", flag_values=flag_values)


def main(argv=None) -> int:
    return commands.run_command(define_flags, pointer_command, argv,
                                prog="python -m kosmos_jax.diagnostics.answer_pointer", doc=__doc__)


def pointer_command(args) -> None:
    try:
        summary = answer_pointer(open_run(args.workdir), args.split, args.step)
    except RunError as error:
        raise SystemExit(f"error: {error}") from None
    if args.json:
        print(json.dumps(summary))
        return
    print(f"step {summary['step']}, split {summary['split']}: the answer's pointed slot is the target's patch / in its quadrant")
    scenes = [(group, summary[group]) for group in ("all", "single", "multi") if group in summary]
    kinds = [(group, shares) for group, shares in sorted(summary["by_kind"].items()) if group != "all"]
    for group, shares in scenes + kinds:
        print(f"  {group:18s} {shares['examples']:5d} examples  cell {shares['cell']:.1%}  quadrant {shares['quadrant']:.1%}")


if __name__ == "__main__":
    sys.exit(main())
