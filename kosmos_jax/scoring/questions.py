"""What the model is asked for each part of an answer: the cue that ends the prompt, the grammar
that admits exactly the answers that parse, the token budget, and the parse of what came back.

The budget is the tokenizer's own spelling of the longest answer the grammar admits (every field
at its longest spelling), plus EOS and a margin. A model that spells an answer in smaller pieces
than the tokenizer would can run out of it; under the constraint it is then steered to a shorter
answer that fits, and unconstrained its answer is cut and fails to parse.
"""

from __future__ import annotations

import dataclasses
import re

from kosmos_jax.grasp_text import ParsedGrasp
from kosmos_jax.instruct.kinds import ANSWERS
from kosmos_jax.models.grammar import CuePrompt, answer_template, cue_constraints, field_domains
from kosmos_jax.text import formatter
from kosmos_jax.text.tokenizer import Tokenizer

_FIELD = re.compile(r"\{(\w+)(?::[^}]*)?\}")
BUDGET_MARGIN = 4


@dataclasses.dataclass(frozen=True)
class Question:
    prompt: CuePrompt  # part, cue, constraint
    max_new_tokens: int

    @property
    def part(self) -> str:
        return self.prompt.part

    def parse(self, ids, config: formatter.FormatConfig) -> tuple[str, ParsedGrasp]:
        """(the target text the generated ids spell, its parse)."""
        answer = self.prompt.target_text(ids)
        return answer, formatter.parse_target(answer, self.part, config)


def longest_answer(config: formatter.FormatConfig, part: str, after_cue: bool) -> str:
    """The text of `part` with every field at its longest spelling (e.g. "x_223,y_223")."""
    fields = field_domains(config.representation, config.angle_code, config.image_size)
    template = answer_template(config.representation, part, after_cue)
    return _FIELD.sub(lambda m: max(fields[m.group(1)].spellings, key=len), template)


def questions(tokenizer: Tokenizer, config: formatter.FormatConfig, vocab_size: int) -> dict[tuple[str, str], Question]:
    """{(answer kind, part): Question} for every answer kind ("grasp", "centre") of the config, for a
    model of `vocab_size` ids (ids past the tokenizer's spell nothing, so are never allowed)."""
    texts = tokenizer.piece_texts()
    texts += [""] * (vocab_size - len(texts))
    asked = {}
    for answer in sorted(set(ANSWERS.values())):
        for prompt in cue_constraints(texts, tokenizer.eos_id, config, answer):
            longest = longest_answer(config, prompt.part, after_cue=config.individual)
            budget = max(prompt.constraint.min_tokens, len(tokenizer.encode(longest)) + 1) + BUDGET_MARGIN
            asked[(answer, prompt.part)] = Question(prompt, budget)
    return asked
