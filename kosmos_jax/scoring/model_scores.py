"""A model's grasps on a split, from its decoded answers: prompts -> greedy answers (with and without
the grammar) -> parses -> one grasp per instruction -> rectangle metric.

    evaluation = GraspEvaluation(model_config, mesh, split, tokenizer, format_config, protocol)
    evaluation.grasp_accuracy(params)       # percent, constrained (what the trainer logs)
    evaluation.target_ceiling()             # percent: the examples' own targets scored as answers
    results, answers = evaluation.results(params)   # both decodings, per kind and scene
    results, answers = evaluation.results(params, unconstrained=False)   # the constrained one alone
    results, answers = evaluation.results(params, mosaic_zoom=True)      # and the mosaics answered again (zoom.py)

Built once per split: the prompts, the batches (each part's prompts left-padded to one length,
the last batch filled with copies of its first row, so each part compiles once), the constraints
and each example's stored target tokens; each call decodes with the parameters it is given.

The target ceiling reads each example's target tokens back as if the model had generated them
(the question's own parse), combines them into grasps and scores them as the answers are: what a
model that reproduced its targets would score. Below 100% it points at the targets, the parse,
the combining of location and angle, or the protocol's w and h, not at the model.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from jax.sharding import Mesh

from kosmos_jax.models.config import Kosmos2Config
from kosmos_jax.models.value_decoding import value_picker
from kosmos_jax.scoring import tally, zoom
from kosmos_jax.scoring.fold_scores import WH_POLICY
from kosmos_jax.scoring.model_answers import Decoder
from kosmos_jax.scoring.instructions import Instruction, combine, combine_asked, group_instructions, text
from kosmos_jax.scoring.prompts import left_padded, prompt, target_ids, written_prompt
from kosmos_jax.scoring.questions import Question, questions
from kosmos_jax.text.formatter import FormatConfig, prompt_cues
from kosmos_jax.text.tokenizer import Tokenizer


def first_instructions(instructions: Sequence[Instruction], max_examples: int) -> list[Instruction]:
    """The leading instructions whose examples number at most `max_examples` (0: all)."""
    if not max_examples:
        return list(instructions)
    kept, used = [], 0
    for instruction in instructions:
        used += len(instruction.examples)
        if used > max_examples:
            break
        kept.append(instruction)
    return kept


class GraspEvaluation:
    def __init__(self, model_config: Kosmos2Config, mesh: Mesh, split, tokenizer: Tokenizer, config: FormatConfig,
                 protocol: str, *, batch_size: int = 16, max_examples: int = 0, backend: str = "exact",
                 value_window: int = 0, angle_window: int = 0):
        """`split`: a StoredSplit, or any sequence of records whose items hold their "image".
        `value_window` > 0 reads coordinate value tokens as the local mean within that many values of
        the mode (`models.value_decoding`); 0 decodes greedily. `angle_window` > 0 reads angle tokens as the
        circular local mean within that many bins of the mode; 0 answers the mode."""
        records = getattr(split, "examples", split)
        self.split, self.config, self.protocol, self.backend = split, config, protocol, backend
        every = group_instructions(records)
        self.instructions = first_instructions(every, max_examples)
        if not self.instructions:
            raise ValueError(f"max_examples={max_examples} holds no whole instruction" if every else "no examples")
        asked = questions(tokenizer, config, model_config.text.vocab_size)
        self.asked, self.tokenizer, self.batch_size = asked, tokenizer, batch_size
        self.question_of: dict[int, Question] = {}
        self.target_ids: dict[int, np.ndarray] = {}  # each example's stored value tokens and </s>
        prompts = {}
        for instruction in self.instructions:
            for part, index in instruction.examples.items():
                question = asked[(instruction.answer, part)]
                self.question_of[index] = question
                prompts[index] = prompt(records[index], tokenizer, question.prompt.cue)
                self.target_ids[index] = target_ids(records[index], tokenizer, question.prompt.cue)
        self.batches = []  # (question, example indices, (ids, mask, image mask))
        for question in dict.fromkeys(self.question_of.values()):
            indices = [i for i, q in self.question_of.items() if q is question]
            length = max(len(prompts[i][0]) for i in indices)
            for start in range(0, len(indices), batch_size):
                rows = indices[start:start + batch_size]
                filled = rows + [rows[0]] * (batch_size - len(rows))
                padded = left_padded([prompts[i] for i in filled], length, tokenizer.pad_id)
                self.batches.append((question, rows, padded))
        self.decoder = Decoder(model_config, mesh, value_picker(tokenizer.piece_texts(), value_window, angle_window))

    @property
    def examples(self) -> int:
        return len(self.question_of)

    def answers(self, params, constrained: bool = True) -> dict[int, tuple[str, object]]:
        """{example index: (answer text, its parse)} of every example (greedy, or value tokens by their local mean)."""
        out = {}
        for question, rows, (ids, mask, image_mask) in self.batches:
            images = np.stack([self.split[i]["image"] for i in rows + [rows[0]] * (len(ids) - len(rows))])
            constraint = question.prompt.constraint if constrained else None
            tokens = self.decoder(params, images, ids, mask, image_mask, constraint, question.max_new_tokens)
            for index, generated in zip(rows, tokens):
                out[index] = question.parse(generated, self.config)
        return out

    def zoomed_grasps(self, params, first: np.ndarray) -> tuple[np.ndarray, dict[int, str]]:
        """([G, 3] each mosaic instruction answered again as NON on the quadrant of its `first` grasp
        ([G, 3], grasps()), in the mosaic's pixels, and NaN for the other instructions; {instruction
        number: the zoomed answer's text}). See zoom.py. Each mosaic is read and enlarged once, every
        part of the answer decoded on it."""
        grasps, texts = np.full((len(self.instructions), 3), np.nan), {}
        mosaics = [g for g, instruction in enumerate(self.instructions) if instruction.scene == "multi"]
        if not mosaics:
            return grasps, texts
        image_of = lambda g: self.split[min(self.instructions[g].examples.values())]["image"]  # a StoredSplit reads it
        corners = zoom.quadrant_corners(first[mosaics, :2], image_of(mosaics[0]).shape[0])  # one view size a split
        asked = [(g, corner) for g, corner in zip(mosaics, corners) if corner[0] >= 0]
        parts = [(part, self.asked[("grasp", part)], written_prompt(self.tokenizer, "", cue))
                 for part, cue in prompt_cues(self.config, "grasp")]
        for start in range(0, len(asked), self.batch_size):
            rows = asked[start:start + self.batch_size]
            views = [zoom.zoomed_view(image_of(g), corner) for g, corner in rows]
            images = np.stack(views + [views[0]] * (self.batch_size - len(rows)))
            parsed, said = [{} for _ in rows], [[] for _ in rows]
            for part, question, (tokens, slots) in parts:
                ids, mask, image_mask = left_padded([(tokens, slots)] * len(images), len(tokens), self.tokenizer.pad_id)
                generated = self.decoder(params, images, ids, mask, image_mask, question.prompt.constraint,
                                         question.max_new_tokens)
                for row, answer in enumerate(generated[:len(rows)]):
                    answer_text, parsed[row][part] = question.parse(answer, self.config)
                    said[row].append(answer_text)
            for row, (g, corner) in enumerate(rows):
                grasps[g] = zoom.from_zoomed(combine_asked("grasp", "", parsed[row])[None], corner[None])[0]
                texts[g] = " ".join(said[row])
        return grasps, texts

    def targets(self) -> dict[int, tuple[str, object]]:
        """{example index: (target text, its parse)} of every example: its stored target tokens read
        as answers() reads generated ones."""
        return {index: self.question_of[index].parse(ids, self.config) for index, ids in self.target_ids.items()}

    def target_ceiling(self) -> float:
        """Percent of instructions whose own targets, scored as answers, make a correct grasp."""
        return tally.percent(self.successes(self.targets()))

    def grasps(self, answers: Mapping[int, tuple[str, object]]) -> np.ndarray:
        """[G, 3] (x, y, theta) of every instruction, NaN where an answer did not parse."""
        return np.stack([combine(instruction, {part: answers[i][1] for part, i in instruction.examples.items()})
                         for instruction in self.instructions])

    def successes(self, answers) -> np.ndarray:
        return tally.successes(self.instructions, self.grasps(answers), self.protocol, self.backend)

    def grasp_accuracy(self, params) -> float:
        """Percent of instructions whose constrained answers make a correct grasp."""
        return tally.percent(self.successes(self.answers(params)))

    def results(self, params, unconstrained: bool = True, mosaic_zoom: bool = False) -> tuple[dict, list[dict]]:
        """(figures of both decodings and of the targets, overall and per kind and scene, and the
        distinct answers and targets; one row per example with both answers). `unconstrained` False
        decodes with the grammar alone (half the time): the unconstrained figures and answers are left out.
        `mosaic_zoom`: also "mosaic_zoom", the figures with every mosaic instruction answered again on
        the quadrant its first answer chose (zoomed_grasps), and each mosaic row's zoom_answer and zoom_correct."""
        held = self.answers(params, constrained=True)
        free = self.answers(params, constrained=False) if unconstrained else None
        held_grasps = self.grasps(held)
        success = tally.successes(self.instructions, held_grasps, self.protocol, self.backend)
        angle_errors = tally.angle_errors(self.instructions, held_grasps)
        free_success = self.successes(free) if unconstrained else None
        zoomed = self.zoom_figures(params, held_grasps, success) if mosaic_zoom else None
        targets = self.targets()
        ceiling = self.successes(targets)
        free_failed = np.array([sum(not free[i][1].ok for i in inst.examples.values())
                                for inst in self.instructions]) if unconstrained else None

        def decoding(hits, answers):
            failures = sum(not parsed.ok for _, parsed in answers.values())
            return {"accuracy": tally.percent(hits), "correct": int(hits.sum()), "answers": len(answers),
                    "parse_failures": failures, "parse_failure_rate": tally.percent(
                        np.array([not parsed.ok for _, parsed in answers.values()]))}

        groups = lambda label: tally.group_figures(self.instructions, success, free_success, free_failed, label,
                                                   ceiling)
        results = {"accuracy": tally.percent(success), "instructions": len(self.instructions),
                   "examples": self.examples, "protocol": self.protocol, "backend": self.backend,
                   "wh_policy": WH_POLICY[self.protocol],
                   "constrained": decoding(success, held),
                   **({"unconstrained": decoding(free_success, free)} if unconstrained else {}),
                   "target_ceiling": tally.percent(ceiling),
                   "distinct": {"answers": tally.distinct(self.instructions, held),
                                "targets": tally.distinct(self.instructions, targets)},
                   "angle_at_centre": tally.angle_fit(angle_errors),
                   "by_kind": groups(lambda i: i.kind), "by_scene": groups(lambda i: i.scene)}
        for scene, members in tally.group_members(self.instructions, lambda i: i.scene).items():
            results["by_scene"][scene]["angle_at_centre"] = tally.angle_fit(angle_errors[members])
        if zoomed is not None:
            results["mosaic_zoom"], zoom_success, zoom_texts = zoomed
        records = getattr(self.split, "examples", self.split)
        rows = [{"example": index, "kind": instruction.kind, "scene": instruction.scene, "part": part,
                 "photo_ids": [text(p) for p in records[index]["photo_ids"]],
                 "instruction": instruction.instruction, "target_text": text(records[index]["target_text"]),
                 "answer": held[index][0], "answer_parses": held[index][1].ok, "correct": bool(success[number]),
                 **({"unconstrained_answer": free[index][0], "unconstrained_parses": free[index][1].ok,
                     "unconstrained_correct": bool(free_success[number])} if unconstrained else {}),
                 **({"zoom_answer": zoom_texts.get(number), "zoom_correct": bool(zoom_success[number])}
                    if zoomed is not None and instruction.scene == "multi" else {}),
                 "target_correct": bool(ceiling[number])}
                for number, instruction in enumerate(self.instructions) for part, index in instruction.examples.items()]
        return results, rows

    def zoom_figures(self, params, first: np.ndarray, success: np.ndarray) -> tuple[dict, np.ndarray, dict[int, str]]:
        """(the "mosaic_zoom" figures, bool [G] whether each instruction hits with the zoom, {instruction
        number: zoomed answer}): single photos keep their first answer; the mosaic instructions right only
        with the zoom and only without it."""
        zoomed, texts = self.zoomed_grasps(params, first)
        mosaic = np.array([instruction.scene == "multi" for instruction in self.instructions])
        hits = tally.successes(self.instructions, np.where(mosaic[:, None], zoomed, first), self.protocol, self.backend)
        figures = {"accuracy": tally.percent(hits), "instructions": len(self.instructions),
                   "by_scene": tally.group_accuracy(self.instructions, hits, lambda i: i.scene),
                   "by_kind": tally.group_accuracy(self.instructions, hits, lambda i: i.kind),
                   "mosaics_right_only_zoomed": int((hits & ~success).sum()),
                   "mosaics_right_only_first": int((success & ~hits).sum())}
        return figures, hits, texts
