"""Fold records carried between a sweep's workdir and a folder that outlives the machine.

    python -m kosmos_jax.experiments --config=C --workdir=runs/fig6 --records_to=results/data_size_demo/folds
    python -m kosmos_jax.experiments --config=C --workdir=runs/fig6 --records_from=results/data_size_demo/folds

A workdir holds checkpoints and datasets (gigabytes) and is gone with its machine; a fold's record
(fold.json, a few kilobytes) is all that aggregation needs. `send_out` copies every record of the
workdir into a folder of the same layout (<arm>/<protocol>-<scheme>-fold<i>/fold.json), one that
can be committed; `bring_in` copies them back into a new workdir, where the runner then skips those
folds and aggregates them with the ones it trains. A record is never replaced by a different one,
and one made by another arm (training config or overrides changed since, or the config file
behind them: the record's recipe) is refused.
"""

from __future__ import annotations

import json
import pathlib

from kosmos_jax.experiments import records, spec


def plain(value):
    """A value as it reads back from JSON (tuples become lists)."""
    return json.loads(json.dumps(value))


def check_same_arm(config, run: spec.Run, record: dict, where: pathlib.Path) -> None:
    entry = config.arms[run.arm]
    wanted = {"arm_config": entry.config, "overrides": plain(spec.dotted(entry.overrides))}
    found = {"arm_config": record.get("arm_config"), "overrides": record.get("overrides")}
    if found != wanted:
        raise spec.ExperimentError(f"{where} was made by arm {run.arm!r} as {found}, but the config's arm is now "
                                   f"{wanted}: its figures would be filed under the wrong arm")


def copy_records(config, source, target, *, check_arm: bool) -> list[str]:
    """Copy the experiment's fold records from `source` to `target` where `target` has none;
    returns the runs copied. Every record is checked before any is written: a different record
    already at `target` (or, with `check_arm`, one made by another arm) copies nothing."""
    todo, arms = [], {}
    for run in spec.runs(config, every=True):
        record = records.read_record(run.workdir(source))
        if record is None:
            continue
        if check_arm:
            where = run.workdir(source) / records.FOLD_FILE
            check_same_arm(config, run, record, where)
            if run.arm not in arms:
                arms[run.arm] = spec.arm_config(config, run.arm)
            spec.check_recipe(record, spec.fold_config(arms[run.arm], run, config.k), where)
        present = records.read_record(run.workdir(target))
        if present is not None and present != record:
            raise spec.ExperimentError(f"{run.workdir(target) / records.FOLD_FILE} already holds another record of "
                                       f"{run.name}: move one of them aside")
        if present is None:
            todo.append((run, record))
    for run, record in todo:
        records.write_json(run.workdir(target) / records.FOLD_FILE, record)
    return [run.name for run, _ in todo]


def bring_in(config, source, root) -> list[str]:
    """Records of `source` (a folder written by send_out) copied into the workdir `root`."""
    if not pathlib.Path(source).is_dir():
        raise spec.ExperimentError(f"--records_from folder {source} does not exist")
    return copy_records(config, source, root, check_arm=True)


def send_out(config, root, target) -> list[str]:
    """Records of the workdir `root` copied into `target`."""
    return copy_records(config, root, target, check_arm=False)
