"""Parameter counts per part of the model, from shapes only (nothing allocated).

    python -m kosmos_jax.models.summary --size kosmos2
"""

from __future__ import annotations

import json
import math
import sys

from absl import flags
from flax import nnx

from kosmos_jax import commands
from kosmos_jax.models import config as config_lib
from kosmos_jax.models.kosmos2 import abstract_model


def summarize(cfg: config_lib.Kosmos2Config) -> dict:
    """{"total": n, "parts": {...}}; the LM head is tied to embed_tokens and so counted once."""
    flat = nnx.to_flat_state(nnx.state(abstract_model(cfg), nnx.Param))
    parts: dict[str, int] = {}
    for path, var in flat:
        keys = [str(k) for k in path]
        if keys[0] == "vision_model":
            part = "vision_model.embeddings" if "embeddings" in keys else "vision_model.encoder" if "encoder" in keys else "vision_model.layer_norms"
        elif keys[0] == "text_model":
            part = "text_model.embed_tokens (tied lm_head)" if "embed_tokens" in keys else "text_model.layers" if "layers" in keys else "text_model.layer_norm"
        else:
            part = keys[0]
        parts[part] = parts.get(part, 0) + math.prod(var.shape)
    return {"total": sum(parts.values()), "parts": dict(sorted(parts.items()))}


def define_flags(flag_values: flags.FlagValues) -> None:
    commands.definer(flag_values)("enum", "size", "kosmos2", "a model size of models/config.py",
                                  enum_values=sorted(config_lib.SIZES))


def main(argv=None) -> int:
    return commands.run_command(
        define_flags, lambda args: print(json.dumps({"size": args.size, **summarize(config_lib.get_config(args.size))},
                                                    indent=2)),
        argv, prog="python -m kosmos_jax.models.summary", doc=__doc__)


if __name__ == "__main__":
    sys.exit(main())
