"""kosmos_e.json: what an exported folder holds besides its weights, so that it is asked as its run was.

export.py writes it beside config.json, model.safetensors and tokenizer.model: the run's text format
(FormatConfig's fields), its tokenizer's id scheme and number mode, its protocol and the grasp size
the predictor lends answers that state none, where it came from (step, workdir), and how its value
tokens and angle tokens are read (value_window, angle_window; folders exported before they were
written are read greedily).
GraspPredictor.from_pretrained reads it. Plain JSON, no jax: the command line looks for it first.
"""

from __future__ import annotations

import json
import pathlib

FORMAT_FILE = "kosmos_e.json"
FIELDS = ("format", "tokenizer", "protocol", "grasp_size", "step", "workdir")


def folder_description(format_fields: dict, scheme: str, numbers: str, protocol: str,
                       grasp_size: tuple[float, float], step: int, workdir, value_window: int = 0,
                       angle_window: int = 0) -> dict:
    return {"format": dict(format_fields), "tokenizer": {"scheme": scheme, "numbers": numbers}, "protocol": protocol,
            "grasp_size": [float(v) for v in grasp_size], "step": int(step), "workdir": str(workdir),
            "value_window": int(value_window), "angle_window": int(angle_window)}


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
