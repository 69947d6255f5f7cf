"""Constrained decoding: a finite-state machine over token strings that only admits grasp answers.

The answer templates come from kosmos_jax.grasp_text. A template is split into literal text and
number fields; each field has a finite set of allowed spellings, exactly the values
`grasp_text.parse_grasp` accepts (`field_domains`), so the answer language is regular. A
character-level automaton (trie nodes for fields, offsets for literals) is run over every token's
string to get a token-level transition table. EOS is a token like the others, spelling an end
marker after the template, so that it completes the last field like any literal would.

An answer is a `part` of formatter's examples: "grasp", the whole answer of joint mode, or in
individual mode the value after a prompt's cue ("location": "x_12,y_3", "angle": "a_77"; the cue
itself ends the prompt). Each part's value template is grasp_text.split_cue of the grasp text. A
location in joint mode (an instruction asking for the centre only) has no cue in the prompt: the
answer writes it (`after_cue=False`).
`cue_constraints` gives the constraint for each prompt a FormatConfig's examples end with.

Orderings the parser demands but a small automaton cannot hold (TLBRA: x1 <= x2 with the box's
middle inside the image; TLBRA-patch: the lower-right patch not left of or above the upper-left
one) use registers: the value of a completed field is stored, and the token-level costs of
kosmos_jax.models.grammar_budget take it into account.

At every step a token is allowed only if a complete answer (EOS included) still fits in the tokens
left after it, so no state without a way out is ever entered and every answer ends in time: every
answer parses. Tokenizer-agnostic: give the text of every token id (`Tokenizer.piece_texts` for
this project's SentencePiece tokenizers) and the EOS id. A token that completes two fields is not
used up to the last field of an order relation (a register holds one value per token).

SentencePiece spells the first token of a segment with a leading "▁" (layout.py encodes the
instruction, the cue and the value each on their own), so the answer may start with one space
(`optional_prefix`); `TokenConstraint.answer` gives the text without it.
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Sequence
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from kosmos_jax import geometry, grasp_text
from kosmos_jax.models import grammar_budget as budget
from kosmos_jax.text import formatter

_FIELD_RE = re.compile(r"\{(\w+)(?::[^}]*)?\}")
END = "\x00"  # the end marker EOS spells; a token whose text holds it is never allowed


@dataclasses.dataclass(frozen=True)
class Field:
    name: str
    spellings: tuple[str, ...]  # every allowed spelling
    values: tuple[int, ...]  # the number each spelling writes (hundredths for radians)


@dataclasses.dataclass(frozen=True)
class Relation:
    lower: str  # field whose value comes first
    upper: str
    kind: str  # "box": lower <= upper, their mean inside the image; "patch": upper's row and column >= lower's


def answer_template(representation: str, part: str = "grasp", after_cue: bool = True) -> str:
    """The text a `part` answer writes, fields in braces: the whole grasp, or the location's or the
    angle's text, only the value after its cue ("x_{x},y_{y}", "a_{a}") when `after_cue`."""
    grasp_text.check_representation(representation)
    formatter.check_part(part)
    location = {
        "xya": grasp_text.CENTRE_TEXT,
        "xywha": grasp_text.CENTRE_TEXT + " " + grasp_text.SIZE_TEXT,
        "tlbra": grasp_text.BOX_TEXT,
        "tlbra_patch": grasp_text.PATCH_TEXT,
    }[representation]
    if part == "grasp":
        return location + " " + grasp_text.ANGLE_TEXT
    text = location if part == "location" else grasp_text.ANGLE_TEXT
    return grasp_text.split_cue(text)[1] if after_cue else text


def _ints(name, lo, hi, width=0):
    return Field(name, tuple(f"{v:0{width}d}" for v in range(lo, hi + 1)), tuple(range(lo, hi + 1)))


def field_domains(representation: str, angle_code: bool, image_size: int) -> dict[str, Field]:
    """Exactly the values parse_grasp accepts, each field alone (relations restrict them jointly):
    centre 0..S-1; w, h 1..2S; box corners -S..2S; patch indices 0..1023 in four digits; angle codes
    0..ANGLE_BINS-1, or radians with two decimals in [-pi/2, pi/2] ("-0.00" included, as
    format_angle writes it)."""
    last = image_size - 1
    cells = grasp_text.PATCH_GRID * grasp_text.PATCH_GRID
    fields = {n: _ints(n, 0, last) for n in ("x", "y")}
    fields.update({n: _ints(n, -image_size, 2 * image_size) for n in ("x1", "y1", "x2", "y2")})
    fields.update(w=_ints("w", 1, 2 * image_size), h=_ints("h", 1, 2 * image_size))
    fields.update(ul=_ints("ul", 0, cells - 1, 4), lr=_ints("lr", 0, cells - 1, 4))
    if angle_code:
        fields["a"] = _ints("a", 0, geometry.ANGLE_BINS - 1)
    else:
        limit = math.floor(100 * math.pi / 2)  # two decimals within [-pi/2, pi/2]
        hundredths = tuple(range(-limit, limit + 1))
        fields["a"] = Field("a", tuple(f"{v / 100:.2f}" for v in hundredths) + ("-0.00",), hundredths + (0,))
    return fields


def relations(representation: str) -> tuple[Relation, ...]:
    if representation == "tlbra":
        return (Relation("x1", "x2", "box"), Relation("y1", "y2", "box"))
    if representation == "tlbra_patch":
        return (Relation("ul", "lr", "patch"),)
    return ()


def relation_holds(kind: str, lower, upper, image_size: int):
    """May `upper` follow `lower` (numbers, broadcast)? As parse_grasp checks the pair."""
    if kind == "box":  # ordered corners whose middle (lower + upper) / 2 lies in [0, S)
        total = lower + upper
        return (upper >= lower) & (total >= 0) & (total <= 2 * image_size - 1)
    grid = grasp_text.PATCH_GRID
    return (upper % grid >= lower % grid) & (upper // grid >= lower // grid)


class _CharMachine:
    """Character-level DFA of one answer template followed by END. State 0 is dead; 1 is the
    start; `final` is the state after END."""

    def __init__(self, template: str, fields: dict[str, Field], optional_prefix: str):
        pieces: list[str | Field] = []
        pos = 0
        for match in _FIELD_RE.finditer(template):
            pieces += [template[pos:match.start()], fields[match.group(1)]]
            pos = match.end()
        pieces = [p for p in [*pieces, template[pos:] + END] if p != ""]
        if any(isinstance(a, Field) and isinstance(b, Field) for a, b in zip(pieces, pieces[1:])):
            raise ValueError(f"template {template!r} has two adjacent fields")
        self.fields = [p for p in pieces if isinstance(p, Field)]
        self.alphabet = sorted(set(optional_prefix).union(*(p for p in pieces if isinstance(p, str)),
                                                          *(s for f in self.fields for s in f.spellings)))
        self.char_index = {c: i for i, c in enumerate(self.alphabet)}
        self.edges: dict[tuple[int, str], tuple[int, int, int]] = {}  # (state, char) -> (state, field, value index)
        self.n_states = 2
        self.inside_value: set[int] = set()  # trie nodes past a field's entry: some digits of a value read
        self.final = self._new()
        entry = self._build(pieces)
        self._copy_edges(entry, 1)
        if optional_prefix:  # e.g. the space SentencePiece puts before the first word
            state = 1
            for ch in optional_prefix[:-1]:
                nxt = self._new()
                self.edges[(state, ch)] = (nxt, -1, -1)
                state = nxt
            self.edges[(state, optional_prefix[-1])] = (entry, -1, -1)

    def _new(self) -> int:
        self.n_states += 1
        return self.n_states - 1

    def _copy_edges(self, source: int, target: int) -> None:
        for (src, ch), edge in list(self.edges.items()):
            if src == source:
                self.edges[(target, ch)] = edge

    def _build(self, pieces) -> int:
        """States from the last piece backwards; returns the entry state of the first piece."""
        after = self.final  # entry state of the piece after the current one
        field_index = len(self.fields)
        for piece in reversed(pieces):
            if isinstance(piece, str):
                states = [self._new() for _ in piece]
                for i, ch in enumerate(piece):
                    self.edges[(states[i], ch)] = (states[i + 1] if i + 1 < len(piece) else after, -1, -1)
                after, after_first = states[0], piece[0]
                continue
            field_index -= 1
            nodes = {"": self._new()}
            index_of = {spelling: i for i, spelling in enumerate(piece.spellings)}
            for spelling in piece.spellings:
                for k in range(1, len(spelling) + 1):
                    if spelling[:k] not in nodes:
                        nodes[spelling[:k]] = self._new()
                        self.edges[(nodes[spelling[:k - 1]], spelling[k - 1])] = (nodes[spelling[:k]], -1, -1)
            self.inside_value.update(node for prefix, node in nodes.items() if prefix)
            for prefix, node in nodes.items():
                if prefix in index_of:  # the first char of the next literal ends the field
                    target = self.edges[(after, after_first)][0]
                    self.edges[(node, after_first)] = (target, field_index, index_of[prefix])
            after = nodes[""]
        return after

    def table(self):
        """(next [S, A], completed field [S, A], completed value [S, A]); dead state 0 maps to 0."""
        shape = (self.n_states, len(self.alphabet))
        nxt, field, value = np.zeros(shape, np.int32), np.full(shape, -1, np.int32), np.full(shape, -1, np.int32)
        for (src, ch), (dst, f, v) in self.edges.items():
            a = self.char_index[ch]
            nxt[src, a], field[src, a], value[src, a] = dst, f, v
        return nxt, field, value

    def run_tokens(self, tokens: Sequence[tuple[str, int]], last_stored: int):
        """Run every (text, id) from every state: (ids [R] of the tokens alive from some state,
        next state [S, R] (0 = dead), completed field [S, R] (-1 none; the last one if several),
        completed value [S, R]). A token completing several fields is kept only where none of them
        is stored in a register (index <= last_stored): a register takes one value per token.
        Texts are visited sorted so that a shared prefix is run once."""
        char_next, char_field, char_value = self.table()
        n = self.n_states
        none = np.full(n, -1, np.int32)
        start = (np.arange(n), none, none, none, np.zeros(n, np.int32))
        stack, previous = [start], ""  # stack[d]: the runs after the first d chars of `previous`
        ids, columns = [], []
        for text, token_id in sorted(t for t in tokens if t[0] and all(ch in self.char_index for ch in t[0])):
            common = 0
            while common < min(len(text), len(previous)) and text[common] == previous[common]:
                common += 1
            del stack[common + 1:]
            for ch in text[common:]:
                states, first, field, value, completed = stack[-1]
                a = self.char_index[ch]
                done = char_field[states, a] >= 0
                stack.append((char_next[states, a], np.where(done & (first < 0), char_field[states, a], first),
                              np.where(done, char_field[states, a], field),
                              np.where(done, char_value[states, a], value), completed + done))
            previous = text
            states, first, field, value, completed = stack[-1]
            states = np.where((completed > 1) & (first <= last_stored), 0, states)
            if states[1:].any():
                ids.append(token_id)
                columns.append((states, field, value))
        if not ids:
            return np.zeros(0, np.int32), *(np.zeros((n, 0), np.int32) for _ in range(3))
        order = np.argsort(ids)  # columns in id order
        return (np.asarray(ids, np.int32)[order],
                *(np.stack([columns[i][j] for i in order], axis=1).astype(np.int32) for j in range(3)))

    def phase_and_order(self):
        """(phase [S]: index of the next field to complete, -1 if unreachable; the reachable states
        in topological order). Every path to a state completes the same number of fields."""
        successors: dict[int, list[tuple[int, int]]] = {}
        for (src, _), (dst, f, _) in self.edges.items():
            successors.setdefault(src, []).append((dst, f))
        stack, reachable = [1], {1}
        while stack:
            for dst, _ in successors.get(stack.pop(), []):
                if dst not in reachable:
                    reachable.add(dst)
                    stack.append(dst)
        indegree = np.zeros(self.n_states, np.int32)
        for src in reachable:
            for dst, _ in successors.get(src, []):
                indegree[dst] += 1
        phase = np.full(self.n_states, -1, np.int32)
        phase[1] = 0
        order, ready = [], [1]
        while ready:  # Kahn's algorithm
            src = ready.pop()
            order.append(src)
            for dst, f in successors.get(src, []):
                phase[dst] = phase[src] + (f >= 0)
                indegree[dst] -= 1
                if indegree[dst] == 0:
                    ready.append(dst)
        return phase, np.asarray(order, np.int64)


class TokenConstraint:
    """The answer grammar over token ids, usable inside jit (see decode.generate's `constraint`).

    `part`: "grasp" (the whole answer), "location" or "angle" (the value after that part's cue, or
    the part's whole text if not `after_cue`; `for_part` takes the settings from a FormatConfig).
    State per row: {"state": automaton state, "reg": spelling index of the completed fields}. A
    token, EOS included, is allowed if the answer can still be completed within the tokens left
    after it. `min_tokens`: the fewest tokens of a whole answer, EOS included.
    """

    def __init__(self, token_texts: Sequence[str], eos_id: int, representation: str = "xya", *,
                 angle_code: bool = True, image_size: int = 224, optional_prefix: str = " ", part: str = "grasp",
                 after_cue: bool = True):
        self.representation, self.angle_code, self.image_size = representation, angle_code, image_size
        self.part = formatter.check_part(part)
        self.eos_id, self.vocab_size = eos_id, len(token_texts)
        self.token_texts, self.optional_prefix = tuple(token_texts), optional_prefix
        fields = field_domains(representation, angle_code, image_size)
        machine = _CharMachine(answer_template(representation, part, after_cue), fields, optional_prefix)
        self.field_names = [f.name for f in machine.fields]
        n_states = machine.n_states
        index = {name: i for i, name in enumerate(self.field_names)}
        kept = [r for r in relations(representation) if r.lower in index]
        stored = [index[name] for r in kept for name in (r.lower, r.upper)]
        tokens = [(text, i) for i, text in enumerate(token_texts) if i != eos_id and END not in text]
        ids, trans, store_field, store_value = machine.run_tokens([*tokens, (END, eos_id)], max(stored, default=-1))
        self.token_ids = np.asarray(ids, np.int32)  # [R]
        self.column_of_token = np.full(self.vocab_size, -1, np.int32)
        self.column_of_token[self.token_ids] = np.arange(ids.size)

        phase, order = machine.phase_and_order()
        neutral = np.ones(n_states, bool)
        neutral[list(machine.inside_value)] = False
        final = np.arange(n_states) == machine.final
        automaton = budget.Automaton(trans, store_field, store_value, final, phase, order,
                                     neutral, tuple(len(f.spellings) for f in machine.fields))
        pairs = tuple(
            budget.Relation(index[r.lower], index[r.upper], relation_holds(
                r.kind, np.asarray(fields[r.lower].values)[:, None], np.asarray(fields[r.upper].values)[None, :],
                image_size))
            for r in kept)
        self.tables = budget.tables(automaton, pairs)
        self.steps = budget.step_tables(self.tables, trans, store_field, store_value)
        self.min_tokens = self.tables.min_tokens
        if self.min_tokens >= budget.INF:
            raise ValueError(f"no sequence of the vocabulary's tokens spells a whole {representation} {part} answer "
                             f"(angle_code={angle_code}, image_size={image_size})")

    @classmethod
    def for_part(cls, token_texts: Sequence[str], eos_id: int, config: formatter.FormatConfig, part: str,
                 **kwargs) -> TokenConstraint:
        """The constraint of one part of `config`'s examples (representation, angle code, image size;
        only individual mode puts a part's cue in the prompt)."""
        return cls(token_texts, eos_id, config.representation, angle_code=config.angle_code,
                   image_size=config.image_size, part=part, after_cue=config.individual, **kwargs)

    def answer(self, ids: Sequence[int]) -> str:
        """The answer that generated ids spell: their texts up to EOS, without the optional prefix.
        (A tokenizer's decode may keep that space: SentencePiece drops a leading "▁" but not a byte
        piece's space.) For a location or angle part this is what follows the prompt's cue."""
        ids = [int(i) for i in ids]
        if self.eos_id in ids:
            ids = ids[:ids.index(self.eos_id)]
        return "".join(self.token_texts[i] for i in ids).removeprefix(self.optional_prefix)

    # -- the interface decode.generate uses -----------------------------------------------------
    def init(self, batch: int):
        return {"state": jnp.ones((batch,), jnp.int32), "reg": jnp.zeros((batch, len(self.field_names)), jnp.int32)}

    def allowed(self, cstate, vocab_size: int, remaining) -> jnp.ndarray:
        """[B, V] bool; `remaining`: tokens the row may still emit, this one included."""
        if vocab_size != self.vocab_size:
            raise ValueError(f"constraint built for {self.vocab_size} tokens, model has {vocab_size}")
        s, reg = cstate["state"], cstate["reg"]
        row = jnp.asarray(self.steps.table)[s].astype(jnp.int32)  # [B, R, C]
        needed = budget.tokens_needed(self.steps, row, reg)
        ok = (row[..., budget.NEXT] > 0) & (needed <= remaining - 1) & budget.completion_allowed(self.steps, row, reg)
        mask = jnp.zeros((s.shape[0], vocab_size), bool).at[:, jnp.asarray(self.token_ids)].set(ok)
        # a row with no choice only arises when called with fewer tokens left than the answer needs
        return mask.at[:, self.eos_id].set(mask[:, self.eos_id] | ~jnp.any(mask, axis=1))

    def advance(self, cstate, tokens):
        s, reg = cstate["state"], cstate["reg"]
        column = jnp.asarray(self.column_of_token)[tokens]
        known = column >= 0
        entry = jnp.asarray(self.steps.table)[s, jnp.maximum(column, 0)].astype(jnp.int32)  # [B, C]
        field, value = entry[:, budget.FIELD], entry[:, budget.VALUE]
        write = known[:, None] & (jnp.arange(reg.shape[1])[None] == field[:, None])
        return {"state": jnp.where(known, entry[:, budget.NEXT], s), "reg": jnp.where(write, value[:, None], reg)}

    def finished(self, cstate):
        return jnp.zeros(cstate["state"].shape, bool)


class CuePrompt(NamedTuple):
    part: str  # "grasp", "location" or "angle"
    cue: str  # what the prompt ends with after the instruction ("" in joint mode)
    constraint: TokenConstraint  # admits exactly what follows the cue

    def target_text(self, ids) -> str:
        """The target text of generated ids (cue and value), as formatter.parse_target takes it."""
        return formatter.target_text(self.cue, self.constraint.answer(ids))


def cue_constraints(token_texts: Sequence[str], eos_id: int, config: formatter.FormatConfig,
                    answer: str = "grasp", **kwargs) -> list[CuePrompt]:
    """One CuePrompt per prompt `formatter.prompt_cues` lists for `config` and `answer` (the
    instruction's answer kind, "grasp" or "centre")."""
    return [CuePrompt(part, cue, TokenConstraint.for_part(token_texts, eos_id, config, part, **kwargs))
            for part, cue in formatter.prompt_cues(config, answer)]
