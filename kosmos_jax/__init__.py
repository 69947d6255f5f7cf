"""kosmos_jax: KOSMOS-E (instruction-following grasping with a multimodal LM) in JAX/Flax.

The packages are the stages of the pipeline, in this order; each imports only from the ones above
it (tests/test_layout.py checks this):
  geometry, grasp_text, publish  conventions (DESIGN.md section 2) and atomic folder writes
  jax_platforms  keeps jax from starting libtpu where there is no TPU (set on import)
  metrics       the rectangle metric
  data          1. readers (Cornell, Jacquard, KOSMOS-E annotations), folds, synthetic scenes
  augment       2. jit augmentation: photos -> 224 views
  annotators    3. each object's words
  instruct      4. INSTRUCT-GRASP samples of every kind, mosaics
  text          5. grasp text, tokenizers, prompt layout
  dataset       6. the build: views of each protocol, samples, array_record files, grain batches
  models        7. KOSMOS-2 in flax.nnx, weights, constrained decoding
  baselines     7. GR-ConvNet and GG-CNN2, the paper's baselines, on the same views and folds
  scoring       8. scores under both protocols: of the baselines, of a model's decoded answers;
                   Fig. 7 drawings
  train         9. the sharded training step, optimiser, checkpoints, the trainer (it scores
                   decoded grasps with scoring's code)
  evaluate      the command `python -m kosmos_jax.evaluate`: a run's scores, overlays
  diagnostics   why a run scores what it scores (answer errors, part oracles, image use, probes)
  experiments, predict  folds and data sizes; one grasp from a trained run (GraspPredictor)
  demo, cli     `make demo`; the `kosmos-grasp` command in front of every entry point

`from kosmos_jax import GraspPredictor` works; it is imported on first use, so `import kosmos_jax`
does not import jax.
"""

import importlib

from kosmos_jax.jax_platforms import quiet_libtpu_without_tpu

__version__ = "0.1.0"

quiet_libtpu_without_tpu()

_LAZY = {"GraspPredictor": "kosmos_jax.predict.predictor", "Grasp": "kosmos_jax.predict.predictor"}


def __getattr__(name):
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'kosmos_jax' has no attribute {name!r}")
