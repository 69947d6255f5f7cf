"""The sweep: every chosen (arm, protocol, scheme, fold) trained, scored and recorded; finished folds skipped.

    summary = run_experiment(config, workdir, command="python -m kosmos_jax.experiments ...")

Per fold, in WORKDIR/<arm>/<protocol>-<scheme>-fold<i>: trainer.train (which resumes a half-trained
run itself), the evaluate command's code, evaluate.run_scores (WORKDIR/.../eval/STEP/; results already there
for the trained step are read, not decoded again), the no-learning predictors on the run's test
instructions (KOSMOS-E arms), then the record fold.json (with, when the arm's data.build holds out a
validation split, the trainer's last validation figures under "validation"). A fold with a record is
skipped. A fold that fails is reported and the sweep goes on; a SIGTERM'd training stops the sweep (SweepStopped) after
the trainer's checkpoint, and the same command resumes; inside sigterm_stops_the_sweep (as the command runs it), a
SIGTERM outside a training (between folds, while a dataset is built or a fold scored) stops it at once, by the
same exception, so the command still copies out the folds it finished. Every fold's config is checked (checks.py:
model shapes, optimiser, batch layout, data settings) and each arm's data source and KOSMOS-2
folder looked up before anything trains, so a bad arm fails at once. A fold's seconds are those of
the invocation that finished it (its record's train.resumed_from says whether an earlier one began it). `train` and `evaluate` are arguments so tests can count calls.
"""

from __future__ import annotations

import contextlib
import copy
import datetime
import json
import pathlib
import signal
import threading
import time
import traceback
from collections.abc import Callable

import jax

from kosmos_jax.experiments import checks, no_learning, records, spec
from kosmos_jax.experiments.aggregate import write_results


class SweepStopped(RuntimeError):
    """Training stopped before its last step (SIGTERM): rerun the same command to resume."""


@contextlib.contextmanager
def sigterm_stops_the_sweep():
    """While inside, a SIGTERM raises SweepStopped where the sweep is, unless a training has put in its own handler
    (train/trainer.Preemption: it saves at the next step and puts this one back). Without it, the signal's default
    action would end the process before the command copies out the folds it finished (--records_to)."""
    if threading.current_thread() is not threading.main_thread():  # only the main thread may set handlers
        yield
        return

    def stop(signum, frame):
        raise SweepStopped("SIGTERM outside a training; rerun the same command to resume")

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def default_train(config, workdir) -> dict:
    from kosmos_jax.train.trainer import train

    return train(config, workdir)


def evaluate_run(workdir: pathlib.Path, step: int, unconstrained: bool = True, mosaic_zoom: bool = False) -> dict:
    """The run's test results at `step`, by the evaluate command's code (written under eval/STEP/);
    `unconstrained` False: without the decoding that ignores the grammar (evaluate's docstring);
    `mosaic_zoom`: with the mosaics answered again on their chosen quadrant (scoring.zoom)."""
    existing = workdir / "eval" / str(step) / "results.json"
    if existing.is_file():
        results = json.loads(existing.read_text())
        if "mosaic_zoom" in results or not mosaic_zoom:
            return results
    from kosmos_jax.evaluate.run_scores import evaluate, write

    results, rows, folder = evaluate(workdir, step=step, unconstrained=unconstrained, mosaic_zoom=mosaic_zoom)
    write(results, rows, folder)
    return results


def no_learning_scores(workdir: pathlib.Path) -> dict | None:
    """The no-learning predictors on a KOSMOS-E run's test instructions (None for a baseline's run)."""
    description = records.run_description(workdir)
    if description.get("config", {}).get("task", "kosmos_e") != "kosmos_e":
        return None
    from kosmos_jax.train.batches import open_dataset

    test = open_dataset(description["dataset_dir"]).splits()["test"].examples
    identity = description["data_identity"]
    return {"tests": no_learning.digest(test),
            "scores": no_learning.score(test, identity["build"]["protocol"], identity["format"]["image_size"])}


def check_startable(arm_config, name: str) -> None:
    """What training needs on this machine before it starts: the source folder (a synthetic set is
    drawn on first use) and, for an arm that must start from KOSMOS-2, the weights' folder."""
    data = arm_config.data
    if data.source != "synthetic":
        from kosmos_jax.train.batches import source_folder

        try:
            source_folder(data)
        except FileNotFoundError as error:
            raise spec.ExperimentError(f"arm {name!r}: {error}") from None
    if arm_config.get("require_init") and not arm_config.get("init_from"):
        raise spec.ExperimentError(f"arm {name!r} starts from KOSMOS-2's weights: give --config.init_from=FOLDER "
                                   "(config.json, model.safetensors, sentencepiece.bpe.model)")
    if arm_config.get("init_from") and not pathlib.Path(arm_config.init_from).is_dir():
        raise spec.ExperimentError(f"arm {name!r}: init_from folder {arm_config.init_from} does not exist")


def now() -> str:
    return datetime.datetime.now().strftime("%H:%M:%S")


def run_fold(config, run: spec.Run, fold_config, root, *, train: Callable, evaluate: Callable, command: str) -> dict:
    """Train, score and record one fold; returns its record."""
    workdir = run.workdir(root)
    fingerprint = spec.recipe(fold_config)
    started = time.perf_counter()
    # the trainer fills in a pretrained start's tokenizer: on a copy, so the record keeps the recipe that
    # a rerun resolves to (and checks) instead of the filled-in one
    summary = train(copy.deepcopy(fold_config), workdir)
    trained = time.perf_counter()
    if not summary.get("finished"):
        raise SweepStopped(f"{run.name}: training stopped at step {summary.get('step')} "
                           f"({summary.get('stopped', 'unfinished')}); rerun the same command to resume")
    results = evaluate(workdir, summary["step"])
    scored = time.perf_counter()
    baselines = no_learning_scores(workdir)
    description = records.run_description(workdir)
    validation = records.validation_evaluation(workdir)
    entry = config.arms[run.arm]
    record = {
        "experiment": config.name, "arm": run.arm, "protocol": run.protocol, "scheme": run.scheme, "fold": run.fold,
        "k": config.k, "series": entry.series, "arm_config": entry.config, "overrides": spec.dotted(entry.overrides),
        "task": spec.task_of(fold_config), "recipe": fingerprint, "workdir": str(workdir),
        "accuracy": results["accuracy"], "by_kind": results.get("by_kind", {}), "by_scene": results.get("by_scene", {}),
        "eval": {key: results.get(key) for key in ("step", "split", "instructions", "examples", "protocol", "backend")},
        "unconstrained": results.get("unconstrained"),
        **({"validation": validation} if validation else {}),  # the trainer's last validation figures, if any
        "training_examples": records.training_examples(description),
        "train": summary,
        "seconds": {"train": round(trained - started, 1), "evaluate": round(scored - trained, 1),
                    "total": round(time.perf_counter() - started, 1)},
        "no_learning": baselines, "machine": records.machine(), "command": command,
        "finished_at": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
    }
    records.write_json(workdir / records.FOLD_FILE, record)
    return record


def finished_line(record: dict) -> str:
    line = f"accuracy {record['accuracy']:.2f}%"
    if record["no_learning"]:
        scores = record["no_learning"]["scores"]
        line += f" (image centre {scores['image_centre']['accuracy']:.2f}%, oracle {scores['gt_mean_oracle']['accuracy']:.2f}%)"
    return line + f", {record['training_examples']} training examples, {record['seconds']['total']:.0f} s"


def run_experiment(config, workdir, *, train: Callable | None = None, evaluate: Callable | None = None,
                   command: str = "", say: Callable[[str], None] = lambda line: print(line, flush=True)) -> dict:
    """Train and score every chosen fold not yet recorded, then aggregate. Returns {"trained",
    "skipped", "failed": [(run name, error)], "results": results.json's content}."""
    train = train or default_train
    evaluate = evaluate or evaluate_run
    root = pathlib.Path(workdir)
    chosen = spec.runs(config)
    arms = {name: spec.arm_config(config, name) for name in dict.fromkeys(r.arm for r in chosen)}
    fold_configs = {run: spec.fold_config(arms[run.arm], run, config.k) for run in chosen}
    for run, fold_config in fold_configs.items():
        checks.check_run(fold_config, run.name)
    for name, arm in arms.items():
        check_startable(arm, name)
    trained, skipped, failed = 0, 0, []
    say(f"[{now()}] experiment {config.name}: {len(chosen)} folds in {root}")
    for number, run in enumerate(chosen, 1):
        where = run.workdir(root)
        record = records.read_record(where)
        if record is not None:
            spec.check_recipe(record, fold_configs[run], where / records.FOLD_FILE)
            say(f"[{now()}] ({number}/{len(chosen)}) {run.name} done, skipped ({where})")
            skipped += 1
            continue
        say(f"[{now()}] ({number}/{len(chosen)}) {run.name}: training in {where}")
        try:
            record = run_fold(config, run, fold_configs[run], root, train=train, evaluate=evaluate, command=command)
        except SweepStopped:
            raise
        except Exception as error:  # noqa: BLE001 - one broken fold must not stop a night's sweep
            say(f"[{now()}] ({number}/{len(chosen)}) {run.name} FAILED: {type(error).__name__}: {error}")
            say("".join(traceback.format_exception(error, limit=-3)).rstrip())
            failed.append((run.name, f"{type(error).__name__}: {error}"))
            continue
        finally:
            jax.clear_caches()  # each arm compiles its own programs; keep memory flat over a long sweep
        trained += 1
        say(f"[{now()}] ({number}/{len(chosen)}) {run.name} finished: {finished_line(record)}")
    results = write_results(config, root, command)
    say(f"[{now()}] wrote {root / 'results.json'} and {root / 'table.md'}")
    return {"trained": trained, "skipped": skipped, "failed": failed, "results": results}
