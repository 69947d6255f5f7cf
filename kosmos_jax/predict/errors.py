"""What a caller of the predictor can get wrong, one exception type each, all PredictError.

Every message names the problem and the input it is about; the command prints it as `error: ...`.
Conversions that lose nothing the model uses (grey, RGBA, 16-bit) are warnings, not errors.
"""

from __future__ import annotations


class PredictError(Exception):
    """Bad input to GraspPredictor or `kosmos-grasp predict`."""


class ImageError(PredictError, ValueError):
    """The image cannot be read or is not a picture the model can take."""


class InstructionError(PredictError, ValueError):
    """The instruction is empty, not text, or longer than the model's context."""


class RunFolderError(PredictError, FileNotFoundError):
    """The workdir or pretrained folder lacks what prediction needs (a checkpoint, a tokenizer, ...)."""


class ImageWarning(UserWarning):
    """An image was converted to 8-bit RGB (grey, alpha channel, 16-bit)."""
