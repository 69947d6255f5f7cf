"""kosmos_e.json: what an exported folder holds besides its weights, so that it is asked as its run was.

export.py writes it beside config.json, model.safetensors and tokenizer.model: the run's text format
(FormatConfig's fields), its tokenizer's id scheme and number mode, its protocol and the grasp size
the predictor lends answers that state none, where it came from (step, workdir, and started_from: the
starts the run was trained from, nearest first, as far as their records reach), and how its value
tokens and angle tokens are read (value_window, angle_window; folders exported before they were
written are read greedily).
GraspPredictor.from_pretrained reads it. Plain JSON, no jax: the command line looks for it first.
"""

from __future__ import annotations

import json
import pathlib

from kosmos_jax.workdir.files import RUN_FILE, read_description as read_run_description

FORMAT_FILE = "kosmos_e.json"
FIELDS = ("format", "tokenizer", "protocol", "grasp_size", "step", "workdir")


def folder_description(format_fields: dict, scheme: str, numbers: str, protocol: str,
                       grasp_size: tuple[float, float], step: int, workdir, value_window: int = 0,
                       angle_window: int = 0, started_from: list[dict] | None = None) -> dict:
    return {"format": dict(format_fields), "tokenizer": {"scheme": scheme, "numbers": numbers}, "protocol": protocol,
            "grasp_size": [float(v) for v in grasp_size], "step": int(step), "workdir": str(workdir),
            "value_window": int(value_window), "angle_window": int(angle_window),
            "started_from": list(started_from or [])}


def start_chain(init: dict | None) -> list[dict]:
    """The starts behind a run whose run.json holds `init` (the trainer's record of config.init_from),
    nearest first: {"folder", "step", "workdir"} for an exported folder (its own kosmos_e.json names
    the run it came from and that run's starts), {"workdir", "step"} for a run's workdir (its own
    run.json names its start). A start that is gone from this machine ends the chain with what the
    record says of it."""
    if not init or "from" not in init:
        return []
    start = pathlib.Path(init["from"])
    if init.get("exported"):
        link = {"folder": str(start), "step": int(init["step"])}
        described = read_description(start) if start.is_dir() else None
        if described is None:
            return [link]
        return [dict(link, workdir=described["workdir"]), *described.get("started_from", [])]
    link = {"workdir": str(start), "step": int(init["step"])}
    if not (start / RUN_FILE).is_file():
        return [link]
    return [link, *start_chain(read_run_description(start).get("init"))]


def write_description(folder, description: dict) -> pathlib.Path:
    path = pathlib.Path(folder) / FORMAT_FILE
    path.write_text(json.dumps(description, indent=2) + "\n")
    return path


def read_description(folder) -> dict | None:
    """FOLDER/kosmos_e.json, or None when the folder has none (e.g. an imported KOSMOS-2)."""
    path = pathlib.Path(folder) / FORMAT_FILE
    if not path.is_file():
        return None
    try:
        description = json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: not JSON ({error})") from None
    missing = [field for field in FIELDS if not isinstance(description, dict) or field not in description]
    if missing:
        raise ValueError(f"{path}: lacks {missing}; export the run again (python -m kosmos_jax.workdir.export)")
    return description
