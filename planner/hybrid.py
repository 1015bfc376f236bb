"""``hybrid``: IGHOA's shape (SA pre-planning → GA over two-part chromosomes → local
optimisation) with what the best mTSP/VRP methods add (docs/ighoa.md, "hybrid").

Beyond ``ighoa`` with its extended local search, each generation:

- polishes with **Or-opt** too (:func:`or_opt`): a segment of 1-3 tasks moved, possibly
  reversed, next to one of its nearest neighbours in the same route, each move evaluated
  in O(1) from the four legs it changes;
- runs an **iterated local search** on the elite (:func:`ils_step`, ``ils_steps`` times):
  a perturbation (:func:`perturb`: ``perturb`` tasks each moved next to a random one of
  its nearest neighbours; for the min-max objectives half of them taken from the longest
  route, the one that sets the cost) followed by the relocate/exchange search between
  routes with don't-look bits (only the moved tasks and their neighbours are looked at
  first, so a step costs O(moves), not O(n)), 2-opt and Or-opt; the result is kept when
  it is better than the elite, and walked on from (record-to-record travel) when it is
  within ``accept`` of it.

The local search between routes also tries 2-opt* (:mod:`planner.moves`: the moves, by
name, each evaluated in O(1)) and, with ``lexicographic``, takes moves that shorten the
fleet's total distance without worsening the objective's figure. One individual of the
first population is a giant tour cut by the optimal split (:func:`giant_tour`).

``ighoa`` stays as the paper has it; these only run under ``--algorithm hybrid``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from planner.cost import evaluate
from planner.ighoa import IGHOAParams
from planner.local_search import allocation_search, optimal_split, past
from planner.moves import mask, ruin_recreate
from planner.operators import improve_routes, leg, two_opt_neighbours
from planner.pins import first_fixed, repair_pins
from planner.population import random_counts
from planner.rng import randint

MAX_SEGMENT = 3  # Or-opt moves segments of 1..MAX_SEGMENT tasks


@dataclass(frozen=True)
class HybridParams(IGHOAParams):
    """IGHOA's settings plus the iterated local search on the elite."""

    ils_steps: int = 5  # perturb-and-improve attempts on the elite per generation
    perturb: int = 3  # tasks moved by one perturbation
    # The ILS runs for the min-max objectives (minmax, makespan); on the sums it did not
    # pay at 10 s (benchmarks/RESULTS.md), unless this is set.
    ils_on_sums: bool = False
    or_opt: bool = True  # Or-opt in the polish
    # The moves between routes of the local search, by name (planner.moves.MOVES);
    # segment_relocate did not pay on kroA200 min-max (benchmarks/RESULTS.md), so it is
    # selectable but off.
    moves: tuple[str, ...] = ("relocate", "exchange", "two_opt_star")
    # Total distance as the local search's second objective, after the objective's own
    # figure (lexicographic): routes that do not set a min-max figure are shortened too.
    lexicographic: bool = True
    # Record-to-record travel in the ILS: a result within ``accept`` (relative) of the
    # elite is walked on from; 0: every step starts from the elite.
    accept: float = 0.01
    # One individual of the first population is a giant tour (nearest neighbour, then
    # 2-opt and Or-opt with neighbour lists) cut optimally into routes (route first,
    # cluster second): what the GA's random orders take long to find on a large instance.
    giant_tour: bool = True
    # Ruin and recreate as the ILS's perturbation (planner.moves.ruin_recreate): this many
    # tasks around a seed (on the longest route for min-max) taken out and put back where
    # they cost least; 0: the neighbour moves of ``perturb`` instead.
    ruin: int = 0

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.ils_steps < 0 or self.perturb < 1 or self.ruin < 0:
            raise ValueError("ils_steps and ruin must be >= 0 and perturb >= 1")
        mask(self.moves)

    @property
    def move_mask(self) -> int:
        """:attr:`moves` as the local search's bit mask."""
        return mask(self.moves)


@njit(cache=True)
def or_opt(perm, begin, count, machine, dist, start_dist, end_dist, neighbours, fixed):  # type: ignore[no-untyped-def]
    """Or-opt on the route ``perm[begin:begin+count]`` of ``machine`` until no move pays:
    a segment of 1..MAX_SEGMENT tasks goes, as it is or reversed, between a nearest
    neighbour of one of its ends and that neighbour's predecessor or successor. The first
    ``fixed`` tasks (a pinned task) stay first. Returns the total gain (distance)."""
    if count < 3:
        return 0.0
    route = perm[begin : begin + count]
    where = np.full(dist.shape[0], -1, dtype=np.int64)
    for p in range(count):
        where[route[p]] = p
    buf = np.empty(count, dtype=np.int64)
    total = 0.0
    improved = True
    while improved:
        improved = False
        for length in range(1, MAX_SEGMENT + 1):
            for i in range(fixed, count - length + 1):
                s0 = route[i]
                s1 = route[i + length - 1]
                a = route[i - 1] if i > 0 else -1
                b = route[i + length] if i + length < count else -2
                removal = (
                    leg(a, s0, machine, dist, start_dist, end_dist)
                    + leg(s1, b, machine, dist, start_dist, end_dist)
                    - leg(a, b, machine, dist, start_dist, end_dist)
                )
                if removal <= 1e-10:
                    continue
                best = 1e-10
                best_p = -2
                best_rev = False
                for end in range(2):
                    node = s0 if end == 0 else s1
                    for q in range(neighbours.shape[1]):
                        w = neighbours[node, q]
                        pw = where[w]
                        if pw < 0:
                            continue
                        for p in (pw - 1, pw):
                            # Edge (route[p], route[p+1]) outside the segment and its legs.
                            if not (p <= i - 2 or p >= i + length) or p < fixed - 1:
                                continue
                            if p < -1 or p >= count:
                                continue
                            u = route[p] if p >= 0 else -1
                            v = route[p + 1] if p + 1 < count else -2
                            base = leg(u, v, machine, dist, start_dist, end_dist)
                            fwd = (
                                leg(u, s0, machine, dist, start_dist, end_dist)
                                + leg(s1, v, machine, dist, start_dist, end_dist)
                                - base
                            )
                            rev = (
                                leg(u, s1, machine, dist, start_dist, end_dist)
                                + leg(s0, v, machine, dist, start_dist, end_dist)
                                - base
                            )
                            if removal - fwd > best:
                                best, best_p, best_rev = removal - fwd, p, False
                            if removal - rev > best:
                                best, best_p, best_rev = removal - rev, p, True
                if best_p == -2:
                    continue
                out = 0
                if best_p == -1:
                    for k in range(length):
                        buf[out] = route[i + length - 1 - k] if best_rev else route[i + k]
                        out += 1
                for idx in range(count):
                    if i <= idx < i + length:
                        continue
                    buf[out] = route[idx]
                    out += 1
                    if idx == best_p:
                        for k in range(length):
                            buf[out] = route[i + length - 1 - k] if best_rev else route[i + k]
                            out += 1
                route[:] = buf
                for p in range(count):
                    where[route[p]] = p
                total += best
                improved = True
    return total


@njit(cache=True)
def or_opt_routes(perm, counts, dist, start_dist, end_dist, neighbours, pins):  # type: ignore[no-untyped-def]
    """:func:`or_opt` on every route of a chromosome; returns the total gain."""
    begin = 0
    total = 0.0
    for i in range(counts.shape[0]):
        fixed = first_fixed(perm, begin, counts[i], i, pins)
        total += or_opt(perm, begin, counts[i], i, dist, start_dist, end_dist, neighbours, fixed)
        begin += counts[i]
    return total


@njit(cache=True)
def _route_at(counts, index):  # type: ignore[no-untyped-def]
    """The route that place ``index`` of the task order belongs to."""
    begin = 0
    for r in range(counts.shape[0]):
        if index < begin + counts[r]:
            return r
        begin += counts[r]
    return counts.shape[0] - 1


@njit(cache=True)
def _move_after(perm, counts, src, w):  # type: ignore[no-untyped-def]
    """Move the task at ``perm[src]`` to just after task ``w``, into w's route."""
    n = perm.shape[0]
    task = perm[src]
    counts[_route_at(counts, src)] -= 1
    for k in range(src, n - 1):
        perm[k] = perm[k + 1]
    at = 0
    while perm[at] != w:
        at += 1
    route_w = _route_at(counts, at)
    for k in range(n - 1, at + 1, -1):
        perm[k] = perm[k - 1]
    perm[at + 1] = task
    counts[route_w] += 1


@njit(cache=True)
def perturb(
    state, perm, counts, route_cost, strength, focus_longest, min_count, pins, neighbours, moved
):  # type: ignore[no-untyped-def]
    """Move ``strength`` random tasks each to just after one of its nearest neighbours,
    picked at random (often in another route); with ``focus_longest``, every other task
    is taken from the route of highest ``route_cost``. A route is never left below
    ``min_count`` and a pinned task never moves (nor has one put before it). The tasks
    moved are written to ``moved`` (the rest -1); returns how many."""
    n = perm.shape[0]
    k = neighbours.shape[1]
    done = 0
    moved[:] = -1
    if k == 0:
        return 0
    for step in range(strength):
        src = randint(state, n)
        if focus_longest and step % 2 == 0:
            longest = int(np.argmax(route_cost))
            if counts[longest] > 0:
                begin = 0
                for r in range(longest):
                    begin += counts[r]
                src = begin + randint(state, counts[longest])
        if counts[_route_at(counts, src)] <= min_count or pins[perm[src]] >= 0:
            continue
        task = perm[src]
        w = neighbours[task, randint(state, k)]
        _move_after(perm, counts, src, w)
        moved[done] = task
        done += 1
    return done


@njit(cache=True)
def local_optimum(
    perm, counts, objective, tables, neighbours, min_count, pins, deadline, dont_look, moves, lexi
):  # type: ignore[no-untyped-def]
    """The ``moves`` between routes from the tasks whose don't-look bit is clear, then
    the neighbour-list 2-opt inside the routes, in place. (Or-opt is left to the
    polish: over every route it costs more than an ILS step is worth.)"""
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    allocation_search(
        perm, counts, objective, tables, neighbours, min_count, 50, pins, deadline, dont_look,
        True, moves, lexi,
    )  # fmt: skip
    improve_routes(perm, counts, dist, start_dist, end_dist, neighbours, pins)


@njit(cache=True)
def ils_step(  # type: ignore[no-untyped-def]
    state,
    elite_perm,
    elite_counts,
    elite_route,
    elite_cost,
    walk_perm,
    walk_counts,
    walk_route,
    walk_cost,
    objective,
    tables,
    neighbours,
    min_count,
    pins,
    steps,
    strength,
    deadline,
    moves,
    lexi,
    accept,
    ruin,
):
    """``steps`` perturb-and-improve attempts from the walk's solution (record-to-record
    travel): a result is the walk's next solution when it costs less than ``1 + accept``
    times the elite, and the new elite when it costs less than the elite (both sets of
    arrays are updated in place). With ``accept`` = 0 the walk is the elite.
    Returns the new elite cost and walk cost."""
    perm = walk_perm.copy()
    counts = walk_counts.copy()
    route = walk_route.copy()
    focus = objective == 3 or objective == 4
    moved = np.empty(max(strength, ruin), dtype=np.int64)
    dont_look = np.empty(perm.shape[0], dtype=np.bool_)
    for _ in range(steps):
        perm[:] = walk_perm
        counts[:] = walk_counts
        if ruin > 0:
            done = ruin_recreate(
                state, perm, counts, objective, tables, neighbours, ruin, focus, min_count,
                pins, moved,
            )  # fmt: skip
        else:
            done = perturb(
                state, perm, counts, walk_route, strength, focus, min_count, pins, neighbours,
                moved,
            )  # fmt: skip
        # Only the moved tasks and their neighbours are looked at first.
        dont_look[:] = True
        for q in range(done):
            dont_look[moved[q]] = False
            for w in neighbours[moved[q]]:
                dont_look[w] = False
        local_optimum(
            perm, counts, objective, tables, neighbours, min_count, pins, deadline, dont_look,
            moves, lexi,
        )  # fmt: skip
        cost = evaluate(perm, counts, objective, tables, route)
        if cost < walk_cost - 1e-12 or cost < elite_cost * (1.0 + accept) - 1e-12:
            walk_perm[:] = perm
            walk_counts[:] = counts
            walk_route[:] = route
            walk_cost = cost
        if cost < elite_cost - 1e-12:
            elite_perm[:] = perm
            elite_counts[:] = counts
            elite_route[:] = route
            elite_cost = cost
    return elite_cost, walk_cost


@njit(cache=True)
def giant_tour(state, perm, counts, objective, tables, neighbours, min_count, pins, deadline):  # type: ignore[no-untyped-def]
    """A first individual, route first and cluster second: one tour through every task
    (nearest neighbour from machine 0's start, then 2-opt and Or-opt with the neighbour
    lists until neither pays) cut by :func:`optimal_split` for the objective; when the
    pins allow no cut, or ``deadline`` passes, a random split repaired for the pins."""
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    n = perm.shape[0]
    m = counts.shape[0]
    free = np.ones(n, dtype=np.bool_)
    prev = -1
    for k in range(n):
        best = -1
        best_d = np.inf
        for t in range(n):
            if free[t]:
                d = start_dist[0, t] if prev < 0 else dist[prev, t]
                if d < best_d:
                    best, best_d = t, d
        perm[k] = best
        free[best] = False
        prev = best
    where = np.full(n, -1, dtype=np.int64)
    gain = 1.0
    while gain > 1e-9 and not past(deadline):
        gain = two_opt_neighbours(perm, 0, n, 0, dist, start_dist, end_dist, neighbours, where, 0)
        gain += or_opt(perm, 0, n, 0, dist, start_dist, end_dist, neighbours, 0)
    random_counts(state, n, m, min_count, counts)
    split = counts.copy()
    if optimal_split(perm, split, objective, tables, min_count, pins, deadline) < np.inf:
        counts[:] = split
    repair_pins(perm, counts, pins, min_count)
