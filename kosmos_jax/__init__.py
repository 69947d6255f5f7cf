"""kosmos_jax: KOSMOS-E (instruction-following grasping with a multimodal LM) in JAX/Flax."""

__version__ = "0.1.0"
