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
import sys

import jax
import jax.numpy as jnp
import numpy as np

from kosmos_jax.models import value_decoding
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.models.value_embeddings import value_tokens
from kosmos_jax.scoring import tally, zoom
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.workdir.run import open_run
from paired_runs import mcnemar_z  # scripts/, this script's folder


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


def share(hits: np.ndarray) -> float:
    """Percent of `hits` true, to two decimals (rounded once)."""
    return round(100.0 * float(np.mean(hits)), 2)


def paired(greedy: np.ndarray, half_mass: np.ndarray) -> dict:
    only_half_mass, only_greedy = int((half_mass & ~greedy).sum()), int((greedy & ~half_mass).sum())
    return {"right_only_half_mass": only_half_mass, "right_only_greedy": only_greedy,
            "z": mcnemar_z(only_half_mass, only_greedy)}


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
    mosaic = np.array([instruction.scene == "multi" for instruction in evaluation.instructions])
    size = records[0]["image"].shape[0]  # every view of a folder's split has one size
    named = zoom.quadrant_corners(np.stack([i.answers[:, :2].mean(0) for i in evaluation.instructions]), size)
    run_decoder = evaluation.decoder
    mass_decoder = type(run_decoder)(run.model_config, mesh, HalfMass(run.tokenizer.piece_texts(),
                                                                      windows["value_window"],
                                                                      windows["angle_window"], size // 2))
    figures = {"workdir": args.workdir, "step": step, "cornell": args.cornell, "mosaic_instructions": int(mosaic.sum())}
    hits, by_kind = {}, {}
    for reading, decoder in (("greedy", run_decoder), ("half_mass", mass_decoder)):
        evaluation.decoder = decoder
        first = evaluation.grasps(evaluation.answers(params))
        evaluation.decoder = run_decoder  # the zoomed view is a single photo: read the run's way
        one_pass = tally.successes(evaluation.instructions, first, evaluation.protocol)
        _, with_zoom, _ = evaluation.zoom_figures(params, first, one_pass)
        in_named = (zoom.quadrant_corners(first[:, :2], size) == named).all(axis=1)
        hits[reading] = (one_pass[mosaic], with_zoom[mosaic])
        figures[reading] = {"one_pass": share(one_pass[mosaic]),
                            "zoomed": share(with_zoom[mosaic]),
                            "named_quadrant": share(in_named[mosaic]),
                            "single_photos": share(one_pass[~mosaic])}
        for g in np.flatnonzero(mosaic):
            counts = by_kind.setdefault(evaluation.instructions[g].kind, {}).setdefault(reading, [0, 0, 0])
            counts[0], counts[1], counts[2] = counts[0] + 1, counts[1] + int(one_pass[g]), counts[2] + int(with_zoom[g])
        print(json.dumps({reading: figures[reading]}), flush=True, file=sys.stderr)
    figures["by_kind"] = by_kind
    figures["paired_one_pass"] = paired(hits["greedy"][0], hits["half_mass"][0])
    figures["paired_zoomed"] = paired(hits["greedy"][1], hits["half_mass"][1])
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
