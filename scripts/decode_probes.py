"""Two ways to read a trained run's centres more precisely, probed on a scored folder (issue 21).

    python scripts/decode_probes.py --workdir=demo_out/run --cornell=datasets/synthetic-300-seed7 \
        --probe=smoothing --sigmas=2,4,8
    python scripts/decode_probes.py --workdir=demo_out/run --cornell=datasets/synthetic-300-seed7 \
        --probe=averaging --steps=400:300,400:200,300,400

smoothing: each coordinate token's mode is taken where the mode's family's probabilities, blurred by a
Gaussian of sigma values, peak (a single favoured value token no longer takes the pick), then read as
the run's local mean around it; averaging: the parameters of the listed checkpoints averaged (each
group separated by ':'), answered with the run's decoding. Prints one JSON line with each arm's
accuracy and angle fit (grammar-constrained answers, honest protocol, the run's windows).
"""

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.models import value_decoding
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.workdir.run import open_run


class SmoothedMode(value_decoding.LocalMean):
    """LocalMean whose coordinate mode is the peak of the blurred distribution."""

    def __init__(self, token_texts, window: int, angle_window: int, sigma: float):
        super().__init__(token_texts, window, angle_window)
        spread = np.arange(self.token_of.shape[1])
        self.kernel = np.exp(-0.5 * ((spread[:, None] - spread[None]) / sigma) ** 2).astype(np.float32)

    def pick(self, logits, allowed):
        token = value_decoding.greedy(logits, allowed)
        if logits.shape[-1] < self.vocab_size:
            return token
        family = jnp.asarray(np.pad(self.family, (0, logits.shape[-1] - self.vocab_size), constant_values=-1))[token]
        table = jnp.asarray(self.token_of)[jnp.maximum(family, 0)]  # [B, R] each value's token
        ids = jnp.maximum(table, 0)
        ok = (table >= 0) & jnp.take_along_axis(allowed, ids, 1)
        probs = jax.nn.softmax(jnp.where(allowed, logits, -jnp.inf), axis=-1)
        blurred = jnp.where(ok, jnp.where(ok, jnp.take_along_axis(probs, ids, 1), 0.0) @ self.kernel, -jnp.inf)
        peak = jnp.take_along_axis(table, jnp.argmax(blurred, axis=-1)[:, None], 1)[:, 0]
        token = jnp.where((family >= 0) & ok.any(-1) & (peak >= 0), peak, token)
        return self._angle(logits, allowed, self._coordinate(logits, allowed, token))


def scored(run, made, params, mesh, picker=None) -> dict:
    evaluation = GraspEvaluation(run.model_config, mesh, made.records, run.tokenizer, run.format_config, "honest",
                                 **value_decoding.configured_windows(run.config))
    if picker is not None:
        evaluation.decoder = type(evaluation.decoder)(run.model_config, mesh, picker)
    figures, _ = evaluation.results(params, unconstrained=False)
    return {"accuracy": figures["accuracy"], "angle_fit": figures["angle_at_centre"]["within_30_deg"],
            "examples": figures["constrained"]["answers"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--cornell", required=True)
    parser.add_argument("--kinds", default="non")
    parser.add_argument("--probe", choices=("smoothing", "averaging"), required=True)
    parser.add_argument("--sigmas", default="2,4,8")
    parser.add_argument("--steps", default="")
    args = parser.parse_args()
    run, mesh = open_run(args.workdir), make_mesh(1, -1, 1)
    made = cornell_examples(args.cornell, run.tokenizer, run.format_config, tuple(args.kinds.split(",")))
    windows = value_decoding.configured_windows(run.config)
    arms = {}
    if args.probe == "smoothing":
        step, params = run.params(None, mesh)
        arms["mode"] = scored(run, made, params, mesh)
        for sigma in (float(s) for s in args.sigmas.split(",")):
            picker = SmoothedMode(run.tokenizer.piece_texts(), windows["value_window"], windows["angle_window"], sigma)
            arms[f"sigma{sigma:g}"] = scored(run, made, params, mesh, picker)
    else:
        step = None
        for group in args.steps.split(":"):
            loaded = [run.params(int(s), mesh)[1] for s in group.split(",")]
            averaged = jax.tree.map(lambda *leaves: sum(leaves) / len(leaves), *loaded)
            arms[f"steps{group}"] = scored(run, made, averaged, mesh)
    print(json.dumps({"workdir": args.workdir, "cornell": args.cornell, "kinds": args.kinds, "probe": args.probe,
                      "step": step, **windows, "arms": arms}))


if __name__ == "__main__":
    main()
