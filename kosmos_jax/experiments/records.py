"""A fold's record (WORKDIR/<arm>/<protocol>-<scheme>-fold<i>/fold.json), what a trained run holds
about itself, and the machine a fold ran on.

The record is written last, atomically (a temporary file renamed into place): it exists only for a
fold that was trained and evaluated to the end, which is what lets the runner skip that fold.
"""

from __future__ import annotations

import json
import os
import pathlib
import platform

import jax

from kosmos_jax.train.metrics_log import read_metrics
from kosmos_jax.workdir.files import RUN_FILE

FOLD_FILE = "fold.json"
BUILD_STATS = "build_stats.json"  # dataset.build.STATS_FILE, beside the dataset a KOSMOS-E run trained on


def write_json(path: pathlib.Path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    staged = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    staged.write_text(json.dumps(data, indent=1) + "\n")
    os.replace(staged, path)


def read_record(workdir) -> dict | None:
    path = pathlib.Path(workdir) / FOLD_FILE
    return json.loads(path.read_text()) if path.is_file() else None


def run_description(workdir) -> dict:
    path = pathlib.Path(workdir) / RUN_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: the trainer writes it when a run starts")
    return json.loads(path.read_text())


def training_examples(description: dict) -> int:
    """Examples in the run's training split: the built dataset's count (KOSMOS-E), or the training
    views (a baseline, one example a view)."""
    if description.get("config", {}).get("task", "kosmos_e") == "baseline":
        return int(description["views"]["train"])
    stats = pathlib.Path(description["dataset_dir"]) / BUILD_STATS
    if not stats.is_file():
        raise FileNotFoundError(f"{stats} is missing: the run's dataset (run.json dataset_dir) is gone")
    return int(json.loads(stats.read_text())["splits"]["train"]["examples"])


def validation_evaluation(workdir) -> dict | None:
    """The trainer's last evaluation on the validation split (its metrics.jsonl line, less "split"),
    or None when the run logged none (its dataset holds no validation split)."""
    found = [r for r in read_metrics(workdir) if r.get("split") == "validation"]
    return {k: v for k, v in found[-1].items() if k != "split"} if found else None


def cpu_model() -> str:
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.partition(":")[2].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine() -> dict:
    """What the fold ran on: platform, processor, CPU counts, jax and its devices."""
    return {"platform": platform.platform(), "python": platform.python_version(), "cpu": cpu_model(),
            "cpu_count": os.cpu_count(), "usable_cpus": len(os.sched_getaffinity(0)), "jax": jax.__version__,
            "backend": jax.default_backend(), "devices": [f"{d.platform}:{d.device_kind}" for d in jax.devices()]}


def machine_text(description: dict) -> str:
    devices = description.get("devices", [])
    kinds = sorted(set(devices))
    return (f"{description.get('cpu', '?')}, {description.get('usable_cpus', '?')} of {description.get('cpu_count', '?')} "
            f"CPUs usable, {len(devices)} jax device(s) ({', '.join(kinds)}), {description.get('platform', '?')}")
