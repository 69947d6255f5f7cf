"""How an exported folder is to be read, from its kosmos_e.json (workdir.pretrained): its tokenizer
file and the tokenizer's id scheme and number mode, its text format, protocol and grasp size, and its
decoding windows (0 for a folder exported before they were written: greedy). The one reading that
GraspPredictor.from_pretrained and the evaluate command's --pretrained share.
"""

from __future__ import annotations

import pathlib

from kosmos_jax.models.value_decoding import WINDOWS
from kosmos_jax.text.formatter import FormatConfig
from kosmos_jax.workdir.files import TOKENIZER_FILE
from kosmos_jax.workdir.pretrained import FORMAT_FILE, read_description


def folder_settings(folder) -> dict:
    """{tokenizer, scheme, numbers, format_config, protocol, grasp_size, step, value_window, angle_window} of the
    exported `folder`; {} when it holds no kosmos_e.json (e.g. an imported KOSMOS-2). ValueError for a
    kosmos_e.json that is not JSON or not of the shape export writes."""
    folder = pathlib.Path(folder)
    described = read_description(folder)
    if described is None:
        return {}
    try:
        return {"tokenizer": folder / TOKENIZER_FILE, "scheme": described["tokenizer"]["scheme"],
                "numbers": described["tokenizer"]["numbers"], "format_config": FormatConfig(**described["format"]),
                "protocol": described["protocol"], "grasp_size": tuple(described["grasp_size"]),
                "step": described["step"], **{name: int(described.get(name, 0)) for name in WINDOWS}}
    except (KeyError, TypeError) as error:  # fields of another shape than export writes
        raise ValueError(f"{folder / FORMAT_FILE}: unreadable ({error!r}); export the run again") from None
