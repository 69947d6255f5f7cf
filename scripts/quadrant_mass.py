"""Which photo of a mosaic the model names, read from the mass of its centre distribution, a probe (issue 22).

    python scripts/quadrant_mass.py --workdir=RUN --cornell=datasets/synthetic-300-seed7 [>> RECORDS.jsonl]

Greedy decoding answers a centre's x token as the mode of its distribution, then y given that x. On
a 2 x 2 mosaic the mode can sit in one photo while most of the probability lies in another. The
`half_mass` reading first picks, for x and then for y, the half of the view (values below or from
half the side) that holds the more probability among the allowed tokens, then the mode within that
half, read as the run's local mean around it within that half. Only the first two coordinate families (x, y) are read
this way; every other token as the run reads it.

Decodes every photo's NON and multi-object instructions of the folder both ways, scores the mosaic
instructions in one pass and zoomed (scoring/zoom.py, the zoomed view always answered the run's way),
and prints one JSON line: each reading's mosaic accuracy, the share of first answers in the named
photo's quadrant, both zoomed accuracies, the paired counts and McNemar's z, and per kind.
"""

import argparse
import json

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.models import value_decoding
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_embeddings import value_tokens
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.workdir.run import open_run


class HalfMass(value_decoding.LocalMean):
    """LocalMean whose x and y modes are taken inside the half of the view that holds more probability."""

    def __init__(self, token_texts, window: int, angle_window: int, half: int):
        super().__init__(token_texts, window, angle_window)
        names = [family for family in value_tokens(token_texts) if family != "a"]  # LocalMean's family order
        self.centre_families = [names.index(name) for name in ("x", "y") if name in names]
        self.half = half

    def pick(self, logits, allowed):
        token = value_decoding.greedy(logits, allowed)
        if logits.shape[-1] < self.vocab_size or not self.centre_families:
            return token
        extra = logits.shape[-1] - self.vocab_size
        family = jnp.asarray(np.pad(self.family, (0, extra), constant_values=-1))
        value = jnp.asarray(np.pad(self.value, (0, extra)))
        mode_family = family[token]
        same = (family[None] == mode_family[:, None]) & allowed
        probs = jax.nn.softmax(jnp.where(allowed, logits, -jnp.inf), axis=-1)
        low = same & (value[None] < self.half)
        high = same & (value[None] >= self.half)
        take_high = jnp.sum(jnp.where(high, probs, 0.0), -1) > jnp.sum(jnp.where(low, probs, 0.0), -1)
        side = jnp.where(take_high[:, None], high, low)
        moved = value_decoding.greedy(logits, side)
        centre = jnp.isin(mode_family, jnp.asarray(self.centre_families)) & side.any(-1)
        token = jnp.where(centre, moved, token)
        kept = jnp.where(centre[:, None], side, allowed)  # the local mean stays inside the chosen half
        return self._angle(logits, allowed, self._coordinate(logits, kept, token))


def quadrants(points: np.ndarray, half: int) -> np.ndarray:
    """int [G] 0..3 the quadrant of each (x, y), -1 where not finite."""
    points = np.asarray(points, np.float64)
    index = (points[:, 0] >= half).astype(int) + 2 * (points[:, 1] >= half).astype(int)
    return np.where(np.isfinite(points).all(-1), index, -1)


def mcnemar(a: np.ndarray, b: np.ndarray) -> dict:
    only_b, only_a = int((b & ~a).sum()), int((a & ~b).sum())
    z = (only_b - only_a) / (only_b + only_a) ** 0.5 if only_b + only_a else 0.0
    return {"right_only_half_mass": only_b, "right_only_greedy": only_a, "z": round(z, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--cornell", required=True)
    args = parser.parse_args()
    run, mesh = open_run(args.workdir), make_mesh(1, -1, 1)
    step, params = run.params(None, mesh)
    records = cornell_examples(args.cornell, run.tokenizer, run.format_config, ("non", "multi")).records
    windows = value_decoding.configured_windows(run.config)
    evaluation = GraspEvaluation(run.model_config, mesh, records, run.tokenizer, run.format_config, "honest", **windows)
    mosaics = np.array([g for g, i in enumerate(evaluation.instructions) if i.scene == "multi"])
    size = records[min(evaluation.instructions[mosaics[0]].examples.values())]["image"].shape[0]
    named = quadrants(np.stack([evaluation.instructions[g].answers[:, :2].mean(0) for g in mosaics]), size // 2)
    run_decoder = evaluation.decoder
    mass_decoder = type(run_decoder)(run.model_config, mesh, HalfMass(run.tokenizer.piece_texts(),
                                                                      windows["value_window"],
                                                                      windows["angle_window"], size // 2))
    figures = {"workdir": args.workdir, "step": step, "cornell": args.cornell, "mosaic_instructions": len(mosaics)}
    hits = {}
    for reading, decoder in (("greedy", run_decoder), ("half_mass", mass_decoder)):
        evaluation.decoder = decoder
        first = evaluation.grasps(evaluation.answers(params))
        evaluation.decoder = run_decoder  # the zoomed view is a single photo: read the run's way
        zoomed, _ = evaluation.zoomed_grasps(params, first)
        one_pass = tally.successes(evaluation.instructions, first, "honest")[mosaics]
        with_zoom = tally.successes(evaluation.instructions, zoomed, "honest")[mosaics]
        single = np.setdiff1d(np.arange(len(evaluation.instructions)), mosaics)
        single_hits = tally.successes(evaluation.instructions, first, "honest")[single]
        hits[reading] = (one_pass, with_zoom)
        figures[reading] = {"one_pass": round(float(one_pass.mean() * 100), 2),
                            "zoomed": round(float(with_zoom.mean() * 100), 2),
                            "named_quadrant": round(float((quadrants(first[mosaics, :2], size // 2) == named).mean() * 100), 2),
                            "single_photos": round(float(single_hits.mean() * 100), 2)}
        by_kind = figures.setdefault("by_kind", {})
        for g, a, b in zip(mosaics, one_pass, with_zoom):
            counts = by_kind.setdefault(evaluation.instructions[g].kind, {}).setdefault(reading, [0, 0, 0])
            counts[0], counts[1], counts[2] = counts[0] + 1, counts[1] + int(a), counts[2] + int(b)
        print(json.dumps({reading: figures[reading]}), flush=True, file=__import__("sys").stderr)
    figures["paired_one_pass"] = mcnemar(hits["greedy"][0], hits["half_mass"][0])
    figures["paired_zoomed"] = mcnemar(hits["greedy"][1], hits["half_mass"][1])
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
