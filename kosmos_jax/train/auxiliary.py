"""The train step's losses beside the next-token loss, as one settings object read from `config.train`.

    auxiliary = AuxiliaryLosses.from_config(config.train)   # missing fields keep their defaults
    make_train_step(..., auxiliary=auxiliary)

Every weight is 0 (off) by default, so KOSMOS-2's own objective is the default; the fields are
documented where the configs set them (configs/kosmos_e.py) and computed in `train.loss`.
"""

from __future__ import annotations

import dataclasses

from kosmos_jax.train.loss import POINTING_TARGETS
from kosmos_jax.train.tower_labels import LABEL_NAMES


@dataclasses.dataclass(frozen=True)
class AuxiliaryLosses:
    pointing_loss: float = 0.0
    pointing_queries: int = 0  # > 0: the pointing loss points only the first this many latent queries
    pointing_target: str = "cell"
    angle_smoothing: float = 0.0  # a width in angle bins; changes the gradient only, not the logged loss
    patch_angle_loss: float = 0.0
    tower_angle_loss: float = 0.0
    slot_angle_loss: float = 0.0
    tower_offset_loss: float = 0.0
    slot_offset_loss: float = 0.0
    answer_pointing_loss: float = 0.0  # needs the slots to be the patches: pointing_target "identity"
    phrase_patch_loss: float = 0.0  # the instruction's words against the tower's grasp patch (train.phrase_patch)
    tower_category_loss: float = 0.0  # the tower's grasp patch read as its object's category (train.tower_labels)
    tower_colour_loss: float = 0.0  # ... and as its object's main colour

    def __post_init__(self):
        if self.pointing_target not in POINTING_TARGETS:
            raise ValueError(f"pointing_target must be one of {POINTING_TARGETS}, got {self.pointing_target!r}")
        if self.answer_pointing_loss and not (self.pointing_loss and self.pointing_target == "identity"):
            raise ValueError("answer_pointing_loss asks the decoder for the target's patch among the image slots, "
                             "which are patches only when the connector is taught so: give pointing_loss > 0 "
                             "and pointing_target='identity'")
        negative = [f.name for f in dataclasses.fields(self)
                    if f.name != "pointing_target" and getattr(self, f.name) < 0]
        if negative:
            raise ValueError(f"auxiliary loss settings must be >= 0: {', '.join(negative)}")

    @classmethod
    def from_config(cls, train_config) -> AuxiliaryLosses:
        """The settings `train_config` (a ConfigDict or mapping) names; those it lacks (older runs' configs) keep their defaults."""
        return cls(**{f.name: train_config[f.name] for f in dataclasses.fields(cls) if f.name in train_config})

    def tower_labels(self) -> tuple[str, ...]:
        """The object labels ("category", "colour") that this run's tower-label losses read (the scene stream's)."""
        return tuple(kind for kind in LABEL_NAMES if getattr(self, f"tower_{kind}_loss"))

    def weights(self) -> dict[str, float]:
        """{name: weight} of the losses this step adds to its objective (and logs), named as they are logged."""
        return {f.name.removesuffix("_loss"): getattr(self, f.name) for f in dataclasses.fields(self)
                if f.name.endswith("_loss") and getattr(self, f.name)}
