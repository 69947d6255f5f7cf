"""Stage 7, the model: KOSMOS-2 in flax.nnx (vision tower, latent-query connector, MAGNETO decoder).

Takes pixels and token ids, gives logits; imports and exports transformers' weights; decodes
answers with a KV cache, constrained to the grasp grammar.
"""
