"""predict: one grasp from a trained run, for a caller's photo and instruction.

Takes a training run's workdir (or an imported KOSMOS-2/KOSMOS-E folder and its tokenizer), photos
of any size and free-form instructions; gives Grasp records in the photo's pixels and, from the
command (`python -m kosmos_jax.predict`, `kosmos-grasp predict`), the overlay of the paper's Fig. 7.
Bad input raises a PredictError subclass that names the problem (errors.py).

GraspPredictor and Grasp are imported on first use, so that `import kosmos_jax.predict` (and the
command's --help) does not import jax.
"""

import importlib

from kosmos_jax.predict.errors import ImageError, ImageWarning, InstructionError, PredictError, RunFolderError

_LAZY = {"GraspPredictor": "kosmos_jax.predict.predictor", "Grasp": "kosmos_jax.predict.predictor"}

__all__ = ["Grasp", "GraspPredictor", "ImageError", "ImageWarning", "InstructionError", "PredictError",
           "RunFolderError"]


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'kosmos_jax.predict' has no attribute {name!r}")
