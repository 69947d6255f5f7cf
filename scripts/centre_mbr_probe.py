"""The answered centre chosen where the model's whole (x, y) distribution puts the most mass nearby (issue 21).

    python scripts/centre_mbr_probe.py --workdir=demo_out/run --cornell=datasets/synthetic-300-seed7 \
        [--kinds=non] [--ranks=16] [--radii=0,3,6,9,12]

A location answer is x, then y given x: the run's decoding reads each as the local mean of its own
distribution around its mode, so for an object whose grasps lie at several places (a long object's
handle and shaft, a mug's body and handle) x may fall between them and y follows that x. Here every
location question is decoded `ranks` times, the i-th time with x forced to the i-th most likely x
value, which gives the joint p(x_i) p(y | x_i) over the `ranks` x values and every y. The centre
answered is the grid point with the most of that mass within `radius` pixels (a minimum-Bayes-risk
choice for a hit that needs the centre within some pixels of a ground truth; radius 0: the joint mode).
Every other answer (angles) stays the run's own. Prints one JSON line: the run's accuracy, and the
accuracy and angle fit with each radius's centres (grammar-constrained answers, honest protocol).
"""

import argparse
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from kosmos_jax.models import value_decoding
from kosmos_jax.models.kosmos2 import abstract_model
from kosmos_jax.models.mesh import make_mesh
from kosmos_jax.scoring import tally
from kosmos_jax.scoring.cornell_examples import cornell_examples
from kosmos_jax.scoring.model_answers import answers_program
from kosmos_jax.scoring.model_scores import GraspEvaluation
from kosmos_jax.workdir.run import open_run


class RankedX(value_decoding.LocalMean):
    """The run's LocalMean, except that an x token is the (row % ranks)-th most likely allowed x value."""

    def __init__(self, token_texts, window: int, angle_window: int, ranks: int):
        super().__init__(token_texts, window, angle_window)
        self.ranks = ranks
        self.x_family = int(self.family[value_decoding.value_tokens(token_texts)["x"][0][0]])

    def pick(self, logits, allowed):
        token = super().pick(logits, allowed)
        family = jnp.asarray(np.pad(self.family, (0, logits.shape[-1] - self.vocab_size), constant_values=-1))
        is_x = family[value_decoding.greedy(logits, allowed)] == self.x_family
        order = jnp.argsort(-jnp.where((family[None] == self.x_family) & allowed, logits, -jnp.inf), axis=-1)
        rank = jnp.arange(logits.shape[0]) % self.ranks
        return jnp.where(is_x, jnp.take_along_axis(order, rank[:, None], 1)[:, 0].astype(token.dtype), token)


def joint_mass(tokens, logits, picker, families) -> tuple[np.ndarray, np.ndarray]:
    """(x values [R], p(x_i) p(y | x_i) [R, Y]) of one example's R decodes."""
    x_ids, x_values = families["x"]
    y_ids, y_values = families["y"]
    x_step = int(np.flatnonzero(np.isin(tokens[0], x_ids))[0])
    y_step = int(np.flatnonzero(np.isin(tokens[0], y_ids))[0])
    p_x = jax.nn.softmax(logits[0, x_step, x_ids])
    p_x = dict(zip(x_values.tolist(), np.asarray(p_x).tolist()))
    chosen = np.array([picker.value[t] for t in tokens[:, x_step]], np.int64)
    order = np.argsort(y_values)
    if not np.array_equal(y_values[order], np.arange(len(y_values))):
        raise ValueError("the y value tokens are not y_0 .. y_N without a gap")
    p_y = np.asarray(jax.nn.softmax(logits[:, y_step][:, y_ids[order]], axis=-1))
    return chosen, np.array([p_x[x] for x in chosen])[:, None] * p_y


def mbr_centre(xs: np.ndarray, mass: np.ndarray, radius: float) -> tuple[int, int]:
    """The (x, y) among xs x every y whose disc of `radius` holds the most of `mass`."""
    score = np.zeros_like(mass)
    cumulative = np.concatenate([np.zeros((len(xs), 1)), np.cumsum(mass, axis=1)], axis=1)
    ys = np.arange(mass.shape[1])
    for i, x in enumerate(xs):
        for j, other in enumerate(xs):
            dx = abs(int(x) - int(other))
            if dx > radius:
                continue
            half = int(np.floor(np.sqrt(radius ** 2 - dx ** 2)))
            low, high = np.clip(ys - half, 0, len(ys)), np.clip(ys + half + 1, 0, len(ys))
            score[i] += cumulative[j, high] - cumulative[j, low]
    i, y = np.unravel_index(np.argmax(score), score.shape)
    return int(xs[i]), int(y)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workdir", required=True)
    parser.add_argument("--cornell", required=True)
    parser.add_argument("--kinds", default="non")
    parser.add_argument("--ranks", type=int, default=16)
    parser.add_argument("--radii", default="0,3,6,9,12")
    args = parser.parse_args()
    run, mesh = open_run(args.workdir), make_mesh(1, -1, 1)
    made = cornell_examples(args.cornell, run.tokenizer, run.format_config, tuple(args.kinds.split(",")))
    windows = value_decoding.configured_windows(run.config)
    evaluation = GraspEvaluation(run.model_config, mesh, made.records, run.tokenizer, run.format_config, "honest", **windows)
    step, params = run.params(None, mesh)
    answers = evaluation.answers(params)
    base = evaluation.grasps(answers)
    arms = {"run": {"accuracy": tally.percent(evaluation.successes(answers))}}

    texts = run.tokenizer.piece_texts()
    families = value_decoding.value_tokens(texts)
    picker = RankedX(texts, windows["value_window"], windows["angle_window"], args.ranks)
    graphdef, _, rest = nnx.split(abstract_model(run.model_config), nnx.Param, ...)
    decode = jax.jit(functools.partial(answers_program, graphdef, rest, picker=picker, return_logits=True),
                     static_argnames=("constraint", "max_new_tokens"))
    masses = {}  # example index -> (xs, mass)
    for question, rows, (ids, mask, image_mask) in evaluation.batches:
        if question.part not in ("location", "grasp"):
            continue
        images = np.stack([made.records[i]["image"] for i in rows + [rows[0]] * (len(ids) - len(rows))])
        repeat = lambda a: np.repeat(np.asarray(a), args.ranks, axis=0)  # noqa: E731
        tokens, logits = decode(params, repeat(images), repeat(ids), repeat(mask), repeat(image_mask),
                                constraint=question.prompt.constraint, max_new_tokens=question.max_new_tokens)
        tokens, logits = np.asarray(tokens), np.asarray(logits)
        for k, index in enumerate(rows):
            block = slice(k * args.ranks, (k + 1) * args.ranks)
            masses[index] = joint_mass(tokens[block], logits[block], picker, families)
    rows_of = [instruction.examples.get("location", instruction.examples.get("grasp")) for instruction in evaluation.instructions]
    for radius in (float(r) for r in args.radii.split(",")):
        grasps = base.copy()
        for g, index in enumerate(rows_of):
            if index in masses and np.isfinite(grasps[g]).all():
                grasps[g, :2] = mbr_centre(*masses[index], radius)
        hits = tally.successes(evaluation.instructions, grasps, "honest")
        fit = tally.angle_fit(tally.angle_errors(evaluation.instructions, grasps))
        arms[f"radius{radius:g}"] = {"accuracy": tally.percent(hits), "angle_fit": fit["within_30_deg"]}
        print(json.dumps({"radius": radius, **arms[f"radius{radius:g}"]}), flush=True)
    print(json.dumps({"workdir": args.workdir, "cornell": args.cornell, "kinds": args.kinds, "step": step,
                      "ranks": args.ranks, **windows, "arms": arms}))


if __name__ == "__main__":
    main()
