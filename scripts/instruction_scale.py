"""How far a connector_instruction run's instruction moves its latent queries, on a batch of its validation split.

    python scripts/instruction_scale.py --workdir=runs/pretrain/stream_instruct

Prints one JSON line: the norms of the instruction's mean embedding as it is now passed (unit root mean
square, `connector_extensions.instruction_bag`) and unscaled (as runs before 2026-11-27 22:00 passed it), of the
connector's dense layer applied to each, of the latent queries, and the largest kernel entry.
"""

import argparse
import json

import jax
import jax.numpy as jnp
from flax import nnx

from kosmos_jax.models.connector_extensions import instruction_mean
from kosmos_jax.models.kosmos2 import abstract_model, split_model
from kosmos_jax.train import batches, step
from kosmos_jax.workdir.run import open_run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", required=True)
    args = parser.parse_args()
    run = open_run(args.workdir)
    if not run.model_config.connector_instruction:
        raise SystemExit(f"error: {args.workdir} has no connector_instruction")
    checkpoint, params = run.params(None)
    graphdef, _, rest = split_model(abstract_model(run.model_config))
    model = nnx.view(nnx.merge(graphdef, params, step.rng_state(rest, jax.random.key(0))), deterministic=True)
    batch = next(batches.eval_batches(run.split("validation"), 32, 0, 1))
    batch = {key: jnp.asarray(batch[key]) for key in step.BATCH_KEYS}
    scaled = step.instruction(model, batch)
    unscaled = instruction_mean(model.text_model.model.embed_tokens.embedding[...], batch["tokens"],
                                step.attention_mask(batch), batch["image_mask"], batch["loss_mask"])
    connector = model.image_to_text_projection
    norm = lambda x: round(float(jnp.linalg.norm(x, axis=-1).mean()), 4)
    print(json.dumps({"workdir": args.workdir, "step": checkpoint, "examples": int(batch["tokens"].shape[0]),
                      "bag_norm": {"unit_rms": norm(scaled), "unscaled": norm(unscaled)},
                      "added_to_queries_norm": {"unit_rms": norm(connector.instruction(scaled)),
                                                "unscaled": norm(connector.instruction(unscaled))},
                      "latent_query_norm": norm(connector.latent_query[...]),
                      "kernel_abs_max": round(float(jnp.abs(connector.instruction.kernel[...]).max()), 4)}))


if __name__ == "__main__":
    main()
