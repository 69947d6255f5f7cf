"""Instruction kinds of INSTRUCT-GRASP and their sentence templates (paper section II, Figs 3-4).

The templates follow the KOSMOS-E paper and the sentences of its public annotation file
(`instructions-original.json`): "Grasp the remote control.", "Grasp the black object.",
"Grasp the object for controlling electronic devices wirelessly.", "Grasp the middle of the
remote control.", "Grasp the object in the top left section of this image.", "Grasp the object
with a rotation angle of a_156 radians.". A strategy instruction is the strategy text itself.
An annotator that holds a whole sentence (the KOSMOS-E file does) is used verbatim; the templates
fill in the words of annotators that only give words (synthetic scenes, rules, a VLM).
"""

from __future__ import annotations

NON = "non"
SINGLE_KINDS = ("angle", "part", "name", "colour", "shape", "purpose", "strategy", "position")
MULTI_KINDS = ("name", "colour", "shape", "purpose", "position", "strategy")
ALL_KINDS = (NON,) + SINGLE_KINDS

# The kinds whose instruction is about one grasp rather than about the whole object.
GRASP_KINDS = ("angle", "part")

TEMPLATES = {
    "angle": "Grasp the object with a rotation angle of a_{code} radians.",
    "part": "Grasp the {part} of the {name}.",
    "name": "Grasp the {name}.",
    "colour": "Grasp the {colour} object.",
    "shape": "Grasp the {shape} object.",
    "purpose": "Grasp the object for {purpose}.",
    "strategy": "{strategy}",
    "position": "Grasp the object in the {position} section of this image.",
}

# What the answer to each kind holds: the angle instruction already gives the angle, so its
# answer is the centre only (paper Fig 3); every other kind is answered with a whole grasp.
ANSWERS = {kind: ("centre" if kind == "angle" else "grasp") for kind in ALL_KINDS}

_ALIASES = {"color": "colour", "none": NON}


def check_kind(kind: str, valid: tuple[str, ...] = ALL_KINDS, scene: str = "an instruction") -> str:
    """The canonical name of `kind`, or ValueError naming it and listing the valid kinds."""
    canonical = _ALIASES.get(str(kind).lower(), str(kind).lower())
    if canonical not in valid:
        raise ValueError(f"unknown instruction kind {kind!r} for {scene}; valid kinds: {', '.join(valid)}")
    return canonical
