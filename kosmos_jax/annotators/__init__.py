"""Stage 3, annotators: photos in, each object's words out (name, colour, shape, purpose, parts...).

base: the ObjectWords record every annotator returns. kosmos_e: the KOSMOS-E authors' annotation
file. synthetic: the synthetic scenes' metadata. rules: colour from pixels, position from grasps
(position.py: the words of a place in the image). vlm: an OpenAI-compatible vision endpoint, cached.
"""

from kosmos_jax.annotators.base import MissingWordsError, ObjectWords

__all__ = ["MissingWordsError", "ObjectWords"]
