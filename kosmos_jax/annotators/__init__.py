"""Annotators: where each object's words come from.

base: the ObjectWords record every annotator returns. kosmos_e: the KOSMOS-E authors' annotation
file. synthetic: the synthetic scenes' metadata. rules: colour from pixels, position from grasps.
vlm: any OpenAI-compatible chat-completions vision endpoint, cached on disk.
"""

from kosmos_jax.annotators.base import MissingWordsError, ObjectWords

__all__ = ["MissingWordsError", "ObjectWords"]
