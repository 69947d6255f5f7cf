"""Constrained decoding: a finite-state machine over token strings that only admits grasp answers.

The answer templates come from kosmos_jax.grasp_text. A template is split into literal text and
number fields; each field has a finite set of allowed spellings (x in 0..image_size-1, angle codes
0..255, zero-padded patch indices, ...), so the answer language is regular. A character-level
automaton (trie nodes for fields, offsets for literals) is run over every token's string to get a
token-level transition table, kept only for the tokens alive from some state.

Orderings the parser demands but a small automaton cannot hold (TLBRA: x2 >= x1 and y2 >= y1;
TLBRA-patch: the lower-right patch not left of or above the upper-left one) use registers: the
value of a completed field is stored, and a token entering or completing a dependent field is
allowed only if some completion still satisfies the relation.

Tokenizer-agnostic: give the text of every token id (SentencePiece's '▁' already turned into a
space) and the EOS id. Tokens spanning two whole fields are not used.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence

import jax.numpy as jnp
import numpy as np

from kosmos_jax import grasp_text

_FIELD_RE = re.compile(r"\{(\w+)(?::[^}]*)?\}")


@dataclasses.dataclass(frozen=True)
class Field:
    name: str
    spellings: tuple[str, ...]  # every allowed spelling
    values: tuple[int, ...]  # the value of each spelling (an index into the relation domain)


@dataclasses.dataclass(frozen=True)
class Relation:
    lower: str  # field whose value must come first
    upper: str
    kind: str  # "ge": upper >= lower; "patch": upper's row and column >= lower's


def answer_template(representation: str) -> str:
    grasp_text.check_representation(representation)
    location = {
        "xya": grasp_text.CENTRE_TEXT,
        "xywha": grasp_text.CENTRE_TEXT + " " + grasp_text.SIZE_TEXT,
        "tlbra": grasp_text.BOX_TEXT,
        "tlbra_patch": grasp_text.PATCH_TEXT,
    }[representation]
    return location + " " + grasp_text.ANGLE_TEXT


def _ints(name, lo, hi, width=0):
    return Field(name, tuple(f"{v:0{width}d}" for v in range(lo, hi + 1)), tuple(range(lo, hi + 1)))


def field_domains(representation: str, angle_code: bool, image_size: int) -> dict[str, Field]:
    """Spellings the parser accepts (kept to values inside the image for box corners)."""
    last = image_size - 1
    cells = grasp_text.PATCH_GRID * grasp_text.PATCH_GRID
    fields = {n: _ints(n, 0, last) for n in ("x", "y", "x1", "y1", "x2", "y2")}
    fields.update(w=_ints("w", 1, 2 * image_size), h=_ints("h", 1, 2 * image_size))
    fields.update(ul=_ints("ul", 0, cells - 1, 4), lr=_ints("lr", 0, cells - 1, 4))
    if angle_code:
        fields["a"] = _ints("a", 0, 255)
    else:  # radians with two decimals in [-pi/2, pi/2], as format_angle writes them
        hundredths = range(-157, 158)
        spellings = tuple(f"{v / 100:.2f}" for v in hundredths) + ("-0.00",)
        fields["a"] = Field("a", spellings, tuple(range(len(spellings))))
    return fields


def relations(representation: str) -> tuple[Relation, ...]:
    if representation == "tlbra":
        return (Relation("x1", "x2", "ge"), Relation("y1", "y2", "ge"))
    if representation == "tlbra_patch":
        return (Relation("ul", "lr", "patch"),)
    return ()


def _relation_holds(kind: str, lower, upper):
    if kind == "ge":
        return upper >= lower
    grid = grasp_text.PATCH_GRID
    return (upper % grid >= lower % grid) & (upper // grid >= lower // grid)


class _CharMachine:
    """Character-level DFA of one answer template. State 0 is dead; 1 is the start."""

    def __init__(self, template: str, fields: dict[str, Field], optional_prefix: str):
        pieces: list[str | Field] = []
        pos = 0
        for match in _FIELD_RE.finditer(template):
            pieces += [template[pos:match.start()], fields[match.group(1)]]
            pos = match.end()
        pieces = [p for p in [*pieces, template[pos:]] if p != ""]
        if any(isinstance(a, Field) and isinstance(b, Field) for a, b in zip(pieces, pieces[1:])):
            raise ValueError(f"template {template!r} has two adjacent fields")
        self.field_names = [p.name for p in pieces if isinstance(p, Field)]
        self.alphabet = sorted(set(template) | set(optional_prefix) |
                               {c for p in pieces if isinstance(p, Field) for s in p.spellings for c in s})
        self.char_index = {c: i for i, c in enumerate(self.alphabet)}
        self.edges: dict[tuple[int, str], tuple[int, int, int]] = {}  # (state, char) -> (state, field, value)
        self.n_states = 2
        self.field_of_state: dict[int, int] = {}  # state inside a field -> field index
        self.completions: dict[int, set[int]] = {}  # state inside a field -> values still reachable
        self.accepting: set[int] = set()
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
        if source in self.accepting:
            self.accepting.add(target)
        if source in self.field_of_state:
            self.field_of_state[target] = self.field_of_state[source]
            self.completions[target] = self.completions[source]

    def _build(self, pieces) -> int:
        """States from the last piece backwards; returns the entry state of the first piece."""
        after = None  # entry state of the piece after the current one (None: end of the answer)
        field_index = len(self.field_names)
        for piece in reversed(pieces):
            if isinstance(piece, str):
                states = [self._new() for _ in piece]
                end = after
                if end is None:
                    end = self._new()
                    self.accepting.add(end)
                for i, ch in enumerate(piece):
                    self.edges[(states[i], ch)] = (states[i + 1] if i + 1 < len(piece) else end, -1, -1)
                after, after_first = states[0], piece[0]
                continue
            field_index -= 1
            nodes = {"": self._new()}
            value_of = dict(zip(piece.spellings, piece.values))
            for spelling, value in value_of.items():
                for k in range(1, len(spelling) + 1):
                    if spelling[:k] not in nodes:
                        nodes[spelling[:k]] = self._new()
                        self.edges[(nodes[spelling[:k - 1]], spelling[k - 1])] = (nodes[spelling[:k]], -1, -1)
                for k in range(len(spelling) + 1):
                    self.completions.setdefault(nodes[spelling[:k]], set()).add(value)
            for prefix, node in nodes.items():
                self.field_of_state[node] = field_index
                if prefix not in value_of:
                    continue
                if after is None:
                    self.accepting.add(node)
                else:  # the first char of the next literal ends the field
                    target = self.edges[(after, after_first)][0]
                    self.edges[(node, after_first)] = (target, field_index, value_of[prefix])
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


class TokenConstraint:
    """The answer grammar over token ids, usable inside jit (see decode.generate's `constraint`).

    State per row: {"state": automaton state, "reg": values of completed fields}. EOS is allowed
    exactly in accepting states.
    """

    def __init__(self, token_texts: Sequence[str], eos_id: int, representation: str = "xya", *,
                 angle_code: bool = True, image_size: int = 224, optional_prefix: str = " "):
        self.representation, self.angle_code, self.image_size = representation, angle_code, image_size
        self.eos_id, self.vocab_size = eos_id, len(token_texts)
        fields = field_domains(representation, angle_code, image_size)
        machine = _CharMachine(answer_template(representation), fields, optional_prefix)
        self.field_names = machine.field_names
        char_next, char_field, char_value = machine.table()
        n_states = machine.n_states

        ids, finals, stored_fields, stored_values = [], [], [], []
        all_states = np.arange(n_states)
        for token_id, text in enumerate(token_texts):
            if token_id == eos_id or not text or any(ch not in machine.char_index for ch in text):
                continue
            states = all_states.copy()
            field = np.full(n_states, -1, np.int32)
            value = np.full(n_states, -1, np.int32)
            completed = np.zeros(n_states, np.int32)
            for ch in text:
                a = machine.char_index[ch]
                done = char_field[states, a] >= 0
                completed += done
                field = np.where(done, char_field[states, a], field)
                value = np.where(done, char_value[states, a], value)
                states = char_next[states, a]
            states = np.where(completed > 1, 0, states)  # a token spanning two whole fields: unused
            if states[1:].any():
                ids.append(token_id), finals.append(states), stored_fields.append(field), stored_values.append(value)
        if not ids:
            raise ValueError(f"no token of the vocabulary can start or continue a {representation} answer")
        self.token_ids = np.asarray(ids, np.int32)  # [R]
        self.trans = np.stack(finals, axis=1).astype(np.int32)  # [S, R], 0 = dead
        self.store_field = np.stack(stored_fields, axis=1)
        self.store_value = np.stack(stored_values, axis=1)
        self.column_of_token = np.full(self.vocab_size, -1, np.int32)
        self.column_of_token[self.token_ids] = np.arange(len(ids))
        self.accepting = np.zeros(n_states, bool)
        self.accepting[list(machine.accepting)] = True

        # registers for order relations between fields
        self.relations = relations(representation)
        index = {name: i for i, name in enumerate(self.field_names)}
        self.rel_lower = np.asarray([index[r.lower] for r in self.relations] or [0], np.int32)
        self.relation_kinds = {r.kind for r in self.relations}
        upper_rel = np.full(len(self.field_names), -1, np.int32)
        for k, rel in enumerate(self.relations):
            upper_rel[index[rel.upper]] = k
        field_of_state = np.full(n_states, -1, np.int32)
        for state, f in machine.field_of_state.items():
            field_of_state[state] = f
        domain = max([len(fields[r.upper].spellings) for r in self.relations] or [1])
        self.completable = np.zeros((n_states, domain), bool)
        for state, values in machine.completions.items():
            if field_of_state[state] >= 0 and upper_rel[field_of_state[state]] >= 0:
                self.completable[state, sorted(values)] = True
        completes_upper = (self.store_field >= 0) & (upper_rel[np.maximum(self.store_field, 0)] >= 0)
        inside_upper = (field_of_state[self.trans] >= 0) & (upper_rel[np.maximum(field_of_state[self.trans], 0)] >= 0)
        self.check_kind = np.where(completes_upper, 2, np.where(inside_upper & (self.trans > 0), 1, 0)).astype(np.int32)
        self.check_rel = np.where(completes_upper, upper_rel[np.maximum(self.store_field, 0)],
                                  np.where(inside_upper, upper_rel[np.maximum(field_of_state[self.trans], 0)], 0))
        self.check_rel = np.maximum(self.check_rel, 0).astype(np.int32)

    # -- the interface decode.generate uses -----------------------------------------------------
    def init(self, batch: int):
        return {"state": jnp.ones((batch,), jnp.int32), "reg": jnp.zeros((batch, len(self.field_names)), jnp.int32)}

    def _holds(self, lower, upper):
        (kind,) = self.relation_kinds
        return _relation_holds(kind, lower, upper)

    min_tokens = 0

    def allowed(self, cstate, vocab_size: int, remaining=None) -> jnp.ndarray:
        if vocab_size != self.vocab_size:
            raise ValueError(f"constraint built for {self.vocab_size} tokens, model has {vocab_size}")
        s = cstate["state"]
        nxt = jnp.asarray(self.trans)[s]  # [B, R]
        ok = nxt > 0
        if self.relations:
            kind, rel = jnp.asarray(self.check_kind)[s], jnp.asarray(self.check_rel)[s]
            lower = jnp.take_along_axis(cstate["reg"], jnp.asarray(self.rel_lower)[rel], axis=1)
            done_ok = self._holds(lower, jnp.asarray(self.store_value)[s])
            domain = jnp.arange(self.completable.shape[1])
            partial_ok = jnp.any(jnp.asarray(self.completable)[nxt] & self._holds(lower[..., None], domain), axis=-1)
            ok &= jnp.where(kind == 2, done_ok, jnp.where(kind == 1, partial_ok, True))
        mask = jnp.zeros((s.shape[0], vocab_size), bool).at[:, jnp.asarray(self.token_ids)].set(ok)
        eos = jnp.asarray(self.accepting)[s] | ~jnp.any(mask, axis=1)  # never leave a row with no choice
        return mask.at[:, self.eos_id].set(eos)

    def advance(self, cstate, tokens):
        s, reg = cstate["state"], cstate["reg"]
        column = jnp.asarray(self.column_of_token)[tokens]
        known = column >= 0
        column = jnp.maximum(column, 0)
        field = jnp.asarray(self.store_field)[s, column]
        value = jnp.asarray(self.store_value)[s, column]
        write = known[:, None] & (jnp.arange(reg.shape[1])[None] == field[:, None])
        return {"state": jnp.where(known, jnp.asarray(self.trans)[s, column], s), "reg": jnp.where(write, value[:, None], reg)}

    def finished(self, cstate):
        return jnp.zeros(cstate["state"].shape, bool)
