"""What the annotation's own chance leaves to a model: its answers against other draws of the same photos' grasps.

    python -m kosmos_jax.diagnostics.annotation_draws --workdir=RUN --scored=cornell-synthetic-300-seed7 \
        [--step=N] [--draws=100] [--candidates=256] [--json]

A synthetic photo's positive grasps are a draw: up to 7 grasps at random places on its parts
(sources/synthetic/scenes.draw_positives). A model sees the photo, never the draw, so no answer is
sure to hit, and how likely an answer is to hit can be measured exactly here: the generator poses the
photo's object again (scenes.posed_photo, checked against the folder's own grasps) and draws its
annotation anew, as often as asked. Every draw is moved into the honest test view as the evaluation
moves the folder's grasps, and scored with the honest protocol. For the single-photo instructions of
a folder that `python -m kosmos_jax.evaluate --cornell=FOLDER` scored, by photo category and overall:

  model           the answers against the folder's own grasps: the evaluate command's accuracy
  model_expected  the same answers against DRAWS fresh draws of each photo (mean of hits): the model's
                  accuracy with the annotation's luck averaged out (the photos' luck stays)
  target_draw     one grasp taken at random from a fresh draw, against DRAWS others: what a model that
                  answers with a sample of its training targets' distribution would score
  parts_draw      the centre of one grasp and the angle of another, each taken at random from its own fresh
                  draw: what a model with individual outputs (the centre and the angle asked apart) that
                  answered samples of its training targets would score
  consensus_draw  target_draw with the draw's consensus grasp (text.target_rows.consensus_row: the one that hits
                  the most of its own draw's grasps) instead of one at random: what the target_grasp
                  "consensus" asks a model to answer
  best_expected   for each photo the one grasp, among up to CANDIDATES grasps of DRAWS fresh draws, that
                  hits the most of DRAWS other draws, scored against a third set of DRAWS draws: the
                  best single answer found for the photo (a lower bound on the best any answer can do)
  best            that grasp against the folder's own grasps

Only folders written by `python -m kosmos_jax.sources.synthetic` can be drawn again. Mosaics are left out.
"""

from __future__ import annotations

import json
import pathlib
import sys
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from absl import flags

from kosmos_jax import commands, geometry
from kosmos_jax.augment.pipeline import move_grasps
from kosmos_jax.dataset.views import HONEST_TEST_CROP, crop_matrices
from kosmos_jax.diagnostics.answer_errors import define_scored_run_flags
from kosmos_jax.diagnostics.categories import synthetic_header
from kosmos_jax.diagnostics.part_oracles import answered_grasps, scored_folder_answers
from kosmos_jax.scoring.instructions import Instruction, group_instructions, text
from kosmos_jax.sources.synthetic import scenes
from kosmos_jax.sources.synthetic.best_grasps import MAX_POSITIVES, hit_rates, padded
from kosmos_jax.sources.synthetic.render import HEIGHT, WIDTH
from kosmos_jax.text.target_rows import consensus_row
from kosmos_jax.workdir.files import RunError

SCORES = ("model", "model_expected", "target_draw", "parts_draw", "consensus_draw", "best_expected", "best")
# the folder's corners are written with 3 decimals (scenes.format_rectangles): a centre moves by at most 5e-4 px
WRITTEN_CENTRE_PX = 1e-2
PHOTO_SETS = ("candidates", "selection", "estimate")  # three independent sets of draws a photo
MAX_ROUNDS = 20


def view_matrix() -> np.ndarray:
    """[2, 3] the honest test view's affine of a synthetic photo (dataset.views.evaluation_views)."""
    matrices = crop_matrices(jax.random.PRNGKey(0)[None], jnp.zeros((1, 1, 5)), jnp.zeros((1, 1), bool),
                             (HEIGHT, WIDTH), HONEST_TEST_CROP)
    return np.asarray(matrices[0])


def in_view(draws: Sequence[Sequence[np.ndarray]], matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(grasps [D, MAX_POSITIVES, 5] in view pixels, mask [D, MAX_POSITIVES]) of draws of photo grasps; a grasp
    whose centre leaves the view is dropped, as the evaluation drops it."""
    grasps, mask = padded(draws)
    moved, kept, _ = move_grasps(jnp.asarray(grasps), jnp.asarray(mask),
                                 jnp.broadcast_to(jnp.asarray(matrix), (len(draws), 2, 3)), HONEST_TEST_CROP.output_size)
    return np.asarray(moved), np.asarray(kept)


def photo_draws(seed: int, index: int, draws: int, draw_seed: int, matrix: np.ndarray,
                own: np.ndarray) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{set name: (grasps, mask) in view}: PHOTO_SETS of `draws` fresh draws of photo `index` of a set
    written with `seed`, after checking that the photo drawn again has the folder's own grasps `own` [N, 5]."""
    scene, posed = scenes.posed_photo(seed, index)
    again, kept = in_view([geometry.corners_to_grasps(scene.positives)], matrix)
    again = again[0][kept[0]]
    if again.shape != own.shape or not np.allclose(again[:, :2], own[:, :2], atol=WRITTEN_CENTRE_PX):
        raise RunError(f"photo {index} of seed {seed} drawn again does not have the folder's grasps: the folder was "
                       "not written by this version of kosmos_jax.sources.synthetic")
    rng = np.random.default_rng([seed, index, draw_seed])
    out = {}
    for name in PHOTO_SETS:
        grasps, mask = np.zeros((0, MAX_POSITIVES, 5), np.float32), np.zeros((0, MAX_POSITIVES), bool)
        for _ in range(MAX_ROUNDS):
            more = in_view([scenes.draw_positives(rng, posed)[0] for _ in range(draws)], matrix)
            # as the generator redraws an empty annotation, and the evaluation leaves out a view that keeps no grasp
            keep = more[1].any(axis=1)
            grasps, mask = np.concatenate([grasps, more[0][keep]]), np.concatenate([mask, more[1][keep]])
            if len(grasps) >= draws:
                break
        else:
            raise RunError(f"photo {index} of seed {seed}: fewer than {draws} of {MAX_ROUNDS * draws} fresh draws keep "
                           "a grasp inside the test view")
        out[name] = (grasps[:draws], mask[:draws])
    return out


def photo_scores(answer: np.ndarray, instruction: Instruction, sets: Mapping[str, tuple[np.ndarray, np.ndarray]],
                 candidates: int, rng: np.random.Generator) -> dict[str, float]:
    """{score: this instruction's hit (0 or 1) or hit rate} (module docstring) for one answered grasp (x, y, theta)."""
    own, own_mask = np.zeros((1, MAX_POSITIVES, 5), np.float32), np.zeros((1, MAX_POSITIVES), bool)
    own[0, :len(instruction.answers)], own_mask[0, :len(instruction.answers)] = instruction.answers, True
    estimate = sets["estimate"]
    pool, pool_mask = sets["candidates"]
    one_each = np.array([rng.choice(np.flatnonzero(row)) for row in pool_mask])
    targets = pool[np.arange(len(pool)), one_each][:, [0, 1, 4]]
    parts = np.concatenate([targets[:, :2], np.roll(targets[:, 2:], 1, axis=0)], axis=1)  # angles of other draws
    consensus = np.stack([row[consensus_row(row)] for row in (grasps[mask] for grasps, mask in zip(pool, pool_mask))])
    every = pool[pool_mask][:, [0, 1, 4]]
    # a fixed number of rows, so that one compiled metric serves every photo: NaN rows never hit
    tried = np.full((candidates, 3), np.nan, np.float32)
    tried[:min(candidates, len(every))] = every[rng.permutation(len(every))[:candidates]]
    chosen = tried[np.argmax(hit_rates(tried, *sets["selection"]))][None]
    own = (own, own_mask)
    if np.isfinite(answer).all():
        model, model_expected = float(hit_rates(answer[None], *own)[0]), float(hit_rates(answer[None], *estimate)[0])
    else:  # an answer that did not parse misses every draw
        model, model_expected = 0.0, 0.0
    return {"model": model, "model_expected": model_expected,
            "target_draw": float(hit_rates(targets, *estimate).mean()),
            "parts_draw": float(hit_rates(parts, *estimate).mean()),
            "consensus_draw": float(hit_rates(consensus[:, [0, 1, 4]], *estimate).mean()),
            "best_expected": float(hit_rates(chosen, *estimate)[0]), "best": float(hit_rates(chosen, *own)[0])}


def annotation_draws(records: Sequence[Mapping], rows: Sequence[Mapping], config, folder, draws: int = 100,
                     candidates: int = 256, draw_seed: int = 0, progress: bool = False) -> dict:
    """{"instructions", "draws", "accuracy": {score: percent}, "categories": {category: {"instructions", score...}}}."""
    if draws < 2 or candidates < 1:
        raise RunError(f"draws must be >= 2 and candidates >= 1, got {draws} and {candidates}")
    header = synthetic_header(folder, "only folders written by python -m kosmos_jax.sources.synthetic can be drawn again")
    instructions = [i for i in group_instructions(records) if i.scene == "single"]
    if not instructions:
        raise RunError(f"{folder}: the scored answers hold no single-photo instruction")
    grasps = answered_grasps(instructions, rows, config)
    matrix, rng = view_matrix(), np.random.default_rng(draw_seed)
    per_photo = []
    for number, (instruction, answer) in enumerate(zip(instructions, grasps)):
        photo = text(records[min(instruction.examples.values())]["photo_ids"][0])
        if photo not in header["photos"]:
            raise RunError(f"photo {photo} is not in {folder}'s {scenes.META_NAME}")
        index = int(photo.removeprefix("pcd")) - scenes.FIRST_NUMBER
        sets = photo_draws(header["seed"], index, draws, draw_seed, matrix, instruction.answers)
        per_photo.append((header["photos"][photo]["category"], photo_scores(answer, instruction, sets, candidates, rng)))
        if progress and ((number + 1) % 25 == 0 or number + 1 == len(instructions)):
            print(f"annotation draws: {number + 1}/{len(instructions)} photos", file=sys.stderr, flush=True)

    def summary(members):
        return {"instructions": len(members),
                **{name: round(100 * float(np.mean([scores[name] for scores in members])), 2) for name in SCORES}}
    categories = sorted({category for category, _ in per_photo})
    return {"instructions": len(per_photo), "draws": draws, "candidates": candidates, "draw_seed": draw_seed,
            "accuracy": summary([scores for _, scores in per_photo]),
            "categories": {c: summary([scores for category, scores in per_photo if category == c]) for c in categories}}


def define_flags(flag_values: flags.FlagValues) -> None:
    define_scored_run_flags(flag_values)
    define = commands.definer(flag_values)
    define("integer", "draws", 100, "fresh draws of each photo's grasps in each of the three sets", lower_bound=2)
    define("integer", "candidates", 256, "grasps of the candidate draws tried as a photo's best answer", lower_bound=1)
    define("integer", "draw_seed", 0, "seed of the fresh draws", lower_bound=0)


def main(argv=None) -> int:
    return commands.run_command(define_flags, draws_command, argv, prog="python -m kosmos_jax.diagnostics.annotation_draws",
                                doc=__doc__)


def draws_command(args) -> None:
    try:
        run, step, records, _, folder, answers = scored_folder_answers(
            args, "only a scored synthetic folder can be drawn again")
        figures = {"step": step, "scored": args.scored,
                   **annotation_draws(records, answers, run.format_config, folder, args.draws, args.candidates,
                                      args.draw_seed, progress=not args.json)}
    except RunError as error:
        raise SystemExit(f"error: {error}") from None
    if args.json:
        print(json.dumps(figures))
        return
    print(f"step {step}, {figures['instructions']} single-photo instructions of {args.scored}, {args.draws} draws a set: "
          "accuracy in percent")
    print(f"{'category':<20}{'instructions':>13}" + "".join(f"{name:>15}" for name in SCORES))
    rows = [("all", figures["accuracy"]), *sorted(figures["categories"].items(), key=lambda item: item[1]["model"])]
    for category, row in rows:
        print(f"{category:<20}{row['instructions']:>13}" + "".join(f"{row[name]:>15.2f}" for name in SCORES))


if __name__ == "__main__":
    sys.exit(main())
