"""How many tokens a grasp answer still needs: the cost-to-go tables behind TokenConstraint.

The token-level automaton of the answer grammar is acyclic (every token moves forward in the
answer), so the fewest tokens from a state to the end is one backward pass. A state's `phase` is
the index of the next field to complete. Costs count every token still to come, EOS included:
EOS is the token that ends the last field (it spells the answer's end marker), and the final state
after it needs 0.

Order relations (TLBRA: x2 >= x1, ...) make the cost depend on stored field values. The cost from
(state, registers) is kept a sum of terms, each a table over (state, one value):

    base[state] + sum over relations k whose lower field is stored:
        upper_cost[k][state, lower value]   when the state is in k's upper field's phase
        remainder[k][lower value]           when k's upper field is still ahead

Field by field, backwards, the cost of completing a field with each value is a shortest path
whose last token pays what the landing state and the value leave to come. That stays a table over
(state, value) except where the next field is the upper of an older relation (TLBRA: y1 then x2,
x2 then y2): there the cost after the boundary depends on where the field ended AND on an older
register, so the field is priced as ending at one landing state (reached by a completing token,
preferring one where no digit of the next value is read yet, the cheapest beyond) and the rest
is carried by that relation's remainder.

Decoding may take any token; it keeps those after which such an answer still fits the budget.
These costs are exact for XYA, XYWHA and TLBRA-patch; for TLBRA they are an upper bound (an answer
ending x2 or y1 elsewhere may be shorter). Either way a kept token never leads into a dead end.

All of a step's lookups depend only on (state, token column), so `step_tables` composes the tables
above with the token transitions once: a decoding step gathers one row by state, then compares.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

INF = 10_000  # "cannot finish": larger than any budget, and three of them still fit in int32


@dataclasses.dataclass(frozen=True)
class Automaton:
    """The token-level automaton; states are those of the character automaton (0 is dead)."""

    trans: np.ndarray  # [S, R] next state per usable token column, 0 = dead
    field: np.ndarray  # [S, R] index of the field the token completes, -1 none
    value: np.ndarray  # [S, R] index (into the field's spellings) of the completed value
    final: np.ndarray  # [S] bool: the state after EOS
    phase: np.ndarray  # [S] index of the next field to complete; -1 for the dead or unreachable
    order: np.ndarray  # [S] the states in an order every token moves forward in
    neutral: np.ndarray  # [S] bool: no digit of a value read yet (a literal, or a field's entry)
    domain_sizes: tuple[int, ...]  # spellings per field


@dataclasses.dataclass(frozen=True)
class Relation:
    lower: int  # field index
    upper: int
    holds: np.ndarray  # [D_lower, D_upper] bool: may the upper value follow the lower one


@dataclasses.dataclass(frozen=True)
class Tables:
    base: np.ndarray  # [S] int32
    phase: np.ndarray  # [S] int32
    relations: tuple[Relation, ...]
    upper_row: tuple[np.ndarray, ...]  # per relation: [S] row of upper_cost, -1 outside the upper's phase
    upper_cost: tuple[np.ndarray, ...]  # per relation: [rows, D_lower] int32
    remainder: tuple[np.ndarray, ...]  # per relation: [D_lower] int32

    @property
    def min_tokens(self) -> int:
        """The fewest tokens (EOS included) of a whole answer, from the start state 1."""
        return int(self.base[1])


def _tail_costs(a: Automaton, after: int) -> np.ndarray:
    """Exact fewest tokens to the end from every state of phase > `after`."""
    cost = np.full(len(a.phase), INF, np.int64)
    for q in a.order[::-1]:
        if a.phase[q] <= after:
            continue
        nxt = a.trans[q][a.trans[q] > 0]
        best = 0 if a.final[q] else INF
        if nxt.size:
            best = min(best, 1 + int(cost[nxt].min()))
        cost[q] = best
    return cost


def _field_costs(a: Automaton, i: int, after: np.ndarray) -> np.ndarray:
    """[S, D_i]: fewest tokens from each phase-i state to complete field i with each value, plus
    after[landing state, value] for the token that completes it."""
    cost = np.full((len(a.phase), a.domain_sizes[i]), INF, np.int64)
    for q in a.order[::-1]:
        if a.phase[q] != i:
            continue
        live = a.trans[q] > 0
        stay = live & (a.field[q] < 0)
        done = live & (a.field[q] == i)
        row = np.full(a.domain_sizes[i], INF, np.int64)
        if stay.any():
            row = np.minimum(row, 1 + cost[a.trans[q, stay]].min(axis=0))
        np.minimum.at(row, a.value[q, done], 1 + after[a.trans[q, done], a.value[q, done]])
        cost[q] = np.minimum(row, INF)
    return cost


def _upper_cost(costs: np.ndarray, states: np.ndarray, holds: np.ndarray) -> np.ndarray:
    """[states, D_lower]: the fewest tokens from each state given the lower value, over the upper
    values the relation allows."""
    table = np.full((len(states), holds.shape[0]), INF, np.int64)
    for r, q in enumerate(states):
        reachable = np.flatnonzero(costs[q] < INF)  # only values extending the digits read so far
        if reachable.size:
            table[r] = np.where(holds[:, reachable], costs[q, reachable], INF).min(axis=1)
    return table


def tables(a: Automaton, relations: tuple[Relation, ...]) -> Tables:
    """Phases from the last relation field back to the first. The cost from (state q of phase p,
    registers) is base[q] (or upper_cost at q when p is an upper field) plus remainder[k] of every
    relation k whose lower field is stored and whose upper field lies beyond phase p."""
    n_states = len(a.phase)
    upper_of = {rel.upper: k for k, rel in enumerate(relations)}
    last = max([f for rel in relations for f in (rel.lower, rel.upper)], default=-1)
    base = _tail_costs(a, last)  # exact after the last relation field
    upper_row = [np.full(n_states, -1, np.int32) for _ in relations]
    upper_cost = [np.zeros((0, rel.holds.shape[0]), np.int64) for rel in relations]
    remainder = [np.full(rel.holds.shape[0], INF, np.int64) for rel in relations]
    for p in range(last, -1, -1):
        # after[landing, value]: what completing field p with `value` at `landing` leaves to pay,
        # beyond the remainders of relations open on both sides of the boundary
        k_next = upper_of.get(p + 1)
        if k_next is not None and relations[k_next].lower < p:
            # field p+1's cost depends on an older register and on where field p ended: price field p
            # as ending at one landing state and carry the rest as that relation's remainder
            ends = np.unique(a.trans[(a.phase[:, None] == p) & (a.field == p) & (a.trans > 0)])
            if ends.size and a.neutral[ends].any():
                ends = ends[a.neutral[ends]]
            after = np.full((n_states, a.domain_sizes[p]), INF, np.int64)
            if ends.size:
                rows = upper_row[k_next][ends]
                landing = ends[np.argmin(upper_cost[k_next][rows].min(axis=1))]
                after[landing] = 0
                remainder[k_next] = upper_cost[k_next][upper_row[k_next][landing]]
        elif k_next is not None:  # field p is that relation's lower field
            after = np.full((n_states, a.domain_sizes[p]), INF, np.int64)
            after[upper_row[k_next] >= 0] = upper_cost[k_next]
        else:
            after = np.repeat(base[:, None], a.domain_sizes[p], axis=1)
        for k, rel in enumerate(relations):
            if rel.lower == p and rel.upper > p + 1:
                after = after + remainder[k][None, :]
        costs = _field_costs(a, p, np.minimum(after, INF))
        states = np.flatnonzero(a.phase == p)
        if p in upper_of:
            k = upper_of[p]
            upper_row[k][states] = np.arange(len(states))
            upper_cost[k] = _upper_cost(costs, states, relations[k].holds)
            base[states] = 0
        else:
            base[states] = costs[states].min(axis=1)
    base[0] = INF
    clip = lambda x: np.minimum(x, INF).astype(np.int32)  # noqa: E731
    return Tables(clip(base), a.phase.astype(np.int32), tuple(relations), tuple(upper_row),
                  tuple(clip(t) for t in upper_cost), tuple(clip(r) for r in remainder))


# -- the decoding step ----------------------------------------------------------------------
NEXT, FIELD, VALUE, COST = range(4)  # channels of StepTables.table; then one term row per relation


@dataclasses.dataclass(frozen=True)
class StepTables:
    """Everything a decoding step reads, per (state, token column): one gather by state gives it.

    table [S, R, 4 + relations] (int16 when everything fits): the NEXT state (0 = dead), the FIELD
    the token completes (-1 none) and its VALUE, the COST from the next state without relation
    terms (Tables.base; INF when dead), then per relation k the row of terms[k] that prices the
    next state: an upper_cost row inside k's upper phase, the remainder row while k's upper field
    is ahead, else a row of zeros."""

    table: np.ndarray
    terms: tuple[np.ndarray, ...]  # per relation: [rows + 2, D_lower] int32
    relations: tuple[Relation, ...]


def step_tables(t: Tables, trans: np.ndarray, field: np.ndarray, value: np.ndarray) -> StepTables:
    """Compose the per-state tables with the token transitions trans/field/value [S, R]."""
    phase = t.phase[trans]
    channels, terms = [trans, field, value, t.base[trans]], []
    for k, rel in enumerate(t.relations):
        rows = len(t.upper_cost[k])
        remainder_row, zero_row = rows, rows + 1
        inside = t.upper_row[k][trans]
        ahead = (rel.lower < phase) & (phase < rel.upper)
        channels.append(np.where(inside >= 0, inside, np.where(ahead, remainder_row, zero_row)))
        terms.append(np.concatenate([t.upper_cost[k], t.remainder[k][None], np.zeros_like(t.remainder[k])[None]]))
    table = np.stack(channels, axis=-1)
    narrow = np.iinfo(np.int16)
    dtype = np.int16 if narrow.min <= table.min() and table.max() <= narrow.max else np.int32
    return StepTables(table.astype(dtype), tuple(terms), t.relations)


def tokens_needed(st: StepTables, row, reg):
    """Fewest tokens (EOS included) to finish after each candidate token, inside jit.

    row: [B, R, C] int32, StepTables.table at each row's state; reg: [B, F] the registers before
    the token. Returns [B, R] int32 (>= INF: cannot finish)."""
    cost = row[..., COST]
    for k, (rel, terms) in enumerate(zip(st.relations, st.terms)):
        lower = jnp.where(row[..., FIELD] == rel.lower, row[..., VALUE], reg[:, rel.lower][:, None])
        cost += jnp.asarray(terms)[row[..., COST + 1 + k], lower]
    return cost


def completion_allowed(st: StepTables, row, reg):
    """[B, R] bool: a token completing a relation's upper field keeps to the relation."""
    field, value = row[..., FIELD], row[..., VALUE]
    ok = jnp.ones(field.shape, bool)
    for rel in st.relations:
        lower = reg[:, rel.lower][:, None]
        ok &= jnp.where(field == rel.upper, jnp.asarray(rel.holds)[lower, jnp.maximum(value, 0)], True)
    return ok
