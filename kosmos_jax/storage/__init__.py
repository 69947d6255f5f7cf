"""Storage and loading: TFDS array_record builders (no TensorFlow) and a grain input pipeline."""
