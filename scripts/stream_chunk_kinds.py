"""How many examples of each instruction kind chunk 0 of a config's scene stream makes (issue 22).

    python scripts/stream_chunk_kinds.py --config=configs/pretrain.py:demo_stream_instruct [--kinds=non,multi]

Prints one JSON line: the stream's kinds, the chunk's examples, its mosaics, and its mosaics whose
instruction names the object in words (every mosaic kind but position), with each kind's count.
"""

import argparse
import collections
import json

from kosmos_jax.experiments.spec import load_config
from kosmos_jax.train import batches, trainer


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", required=True, help="a config file and variant with config.data.stream.photos > 0")
    parser.add_argument("--kinds", default=None, help="config.data.stream.kinds for this count (default: the config's)")
    args = parser.parse_args()
    config = load_config(args.config)
    if args.kinds is not None:
        config.data.stream.kinds = args.kinds
    settings = trainer.stream_settings(config.data)
    if settings is None:
        parser.error(f"{args.config} reads no scene stream (config.data.stream.photos is 0)")
    stream = trainer.scene_batches(config, settings, batches.prepare(config.data).tokenizer())
    labels = stream.chunk(0).labels
    stream.close()
    by_kind = collections.Counter(label.rpartition(" (")[2].rstrip(")") for label in labels)
    mosaic = {kind: n for kind, n in by_kind.items() if kind.startswith("multi-")}
    print(json.dumps({"config": args.config, "stream_kinds": config.data.stream.kinds or "the build's",
                      "examples": len(labels), "mosaics": sum(mosaic.values()),
                      "object_word_mosaics": sum(n for kind, n in mosaic.items() if kind != "multi-position"),
                      "by_kind": dict(sorted(by_kind.items()))}))


if __name__ == "__main__":
    main()
