"""Time to make one scene-stream chunk: 64 scenes uncapped against 256 capped at 4,096 examples
(demo_stream_instruct's build and tokenizer). From the repository root:

    python results/pretrain/probes/chunk_time.py
"""

import time
from kosmos_jax.experiments.spec import load_config
from kosmos_jax.train import batches as batches_lib
from kosmos_jax.train.scene_stream import make_chunk

config = load_config("configs/pretrain.py:demo_stream_instruct")
dataset = batches_lib.prepare(config.data)
build, tokenizer = batches_lib.build_config(config.data), dataset.tokenizer()
for photos, examples in [(64, 0), (256, 4096)]:
    t = time.perf_counter()
    chunk = make_chunk(build, tokenizer, photos, 10_000, 0, examples)
    print(photos, examples, len(chunk.labels), f"{time.perf_counter() - t:.1f} s", flush=True)
