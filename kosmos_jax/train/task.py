"""The seam between the training loop (trainer.train) and what it trains: a Task per config.task.

"kosmos_e" (trainer.kosmos_task): the built dataset's token batches, the language-model step,
decoded grasps. "baseline" (baseline_task): GR-ConvNet or GG-CNN2 on a fold's views.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

from kosmos_jax.train.state import TrainState


@dataclasses.dataclass
class Task:
    """What the loop needs of one kind of run (config.task)."""

    description: dict  # run.json: config, data identity, model (a resume checks the last two)
    batches: Any  # endless host batches with get_state() / set_state()
    init_state: Callable[[], TrainState]
    abstract_state: Callable[[], TrainState]  # the restore target
    train_step: Callable  # (state, host batch) -> (state, metrics)
    step_record: Callable  # (step, metrics, host batch, step_s, waited) -> metrics.jsonl line
    describe: Callable  # host batch -> its examples, for the non-finite error
    # (step, state, with_grasps, log) -> an evaluation's line: `watched_record`'s
    test_record: Callable
    write_files: Callable  # workdir -> None: files beside run.json (process 0)


def check_batch_layout(config, mesh) -> None:
    rows = config.train.batch_size // config.train.microbatches
    data_devices = mesh.shape["data"] * mesh.shape["fsdp"]
    if config.train.batch_size % config.train.microbatches or rows % data_devices:
        raise ValueError(f"train.batch_size={config.train.batch_size} in {config.train.microbatches} microbatches "
                         f"does not split over the {data_devices} data-parallel devices of mesh {dict(mesh.shape)}")


def watched_record(split_record: Callable[[str], dict], has_validation: bool, step: int, last_step: int, log) -> dict:
    """An evaluation's line: the validation split's when there is one, else test's; at `last_step` with a
    validation split, validation's is logged here and test's returned (test is scored once, at the end).
    `split_record(name)` scores split `name`."""
    if not has_validation:
        return split_record("test")
    if step >= last_step:
        log.write(split_record("validation"))
        return split_record("test")
    return split_record("validation")
