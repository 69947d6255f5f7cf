"""Grasp samples as text and tokens: the formatter, the tokenizers and the KOSMOS-2 prompt layout."""
