"""KOSMOS-2 in flax.nnx: vision tower, latent-query connector, MAGNETO decoder, import/export, decoding."""
