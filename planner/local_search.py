"""Our local search beyond the paper: moves of single tasks between routes.

The paper's 2-opt and circle modification (§4.5) only reorder tasks inside the fixed
route boundaries of a chromosome. These moves change the allocation itself, evaluated
exactly under every objective (sums and min-max alike):

- relocate: take a task out of its route and put it next to one of its nearest
  neighbours in another route;
- exchange: swap a task with one of its nearest neighbours in another route;
- for ``hybrid`` also the moves of :mod:`planner.moves` (2-opt*, segment relocate),
  chosen by a bit mask.

Candidate positions come from each task's ``k`` nearest tasks, so a pass costs
O(n k m) rather than O(n^2). Moves are applied best-per-task, first-improvement over tasks,
until a pass finds nothing; then the circle modification tidies each route again.

Both kernels take a ``deadline`` (a :func:`time.monotonic` instant; infinite: none) and
stop early once it has passed (or a stop flag of the solve is set: :func:`stop_on`),
leaving a valid chromosome: :func:`improve_allocation` keeps the moves made so far (looked
at every :data:`CHECK_EVERY` tasks of a pass), :func:`optimal_split` keeps the old cut. A
huge instance's search so ends within its time limit; without a deadline nothing changes.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
from numba import njit, objmode

from planner.cost import fleet_gain, largest_three
from planner.cost import fleet_value as _objective
from planner.cost import route_value as _route_value
from planner.moves import (
    EXCHANGE,
    RELOCATE,
    SEGMENT,
    SEGMENT_RELOCATE,
    TWO_OPT_STAR,
    prefix,
    rows_back,
    segment_apply,
    segment_lengths,
    two_opt_star_allowed,
    two_opt_star_apply,
    two_opt_star_lengths,
    two_opt_star_sizes,
)
from planner.operators import improve_routes, leg

CHECK_EVERY = 64  # tasks (moves tried, or cuts) between two looks at the clock


_run = threading.local()  # .flags: the stop flags of the solve running in this thread


def stop_on(flags: tuple[threading.Event, ...]) -> None:
    """The kernels this thread runs from now on see ``flags``: once one is set, every
    deadline has passed (:func:`clock`). :func:`planner.solve.solve` says so as it starts,
    so that a flag set from another thread stops the long compiled phases too (the giant
    tour's ILS took 5-17 s to see one on 1 000-3 000 tasks)."""
    _run.flags = flags


def clock() -> float:
    """:func:`time.monotonic`, or infinity once a stop flag of this thread's solve is set."""
    if any(flag.is_set() for flag in getattr(_run, "flags", ())):
        return math.inf
    return time.monotonic()


@njit(cache=True)  # object mode: holds the GIL for the call (numba warns of nogil here)
def now() -> float:
    """:func:`clock`, from compiled code."""
    with objmode(t="float64"):
        t = clock()
    return t


@njit(cache=True, nogil=True)
def past(deadline: float) -> bool:
    """Whether ``deadline`` (a monotonic instant; infinite: none) has passed."""
    return deadline < np.inf and now() >= deadline


NEIGHBOUR_BLOCK = 256  # rows of the distance matrix looked at together (memory: not n x n)


def nearest_neighbours(dist: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` nearest other tasks of every task, nearest first. Works on
    :data:`NEIGHBOUR_BLOCK` rows at a time, so its scratch stays O(n) rows' worth, not a
    second n x n matrix (and its argpartition) beside ``dist``."""
    n = dist.shape[0]
    k = max(0, min(k, n - 1))
    out = np.zeros((n, k), dtype=np.int64)
    if k == 0:
        return out
    for lo in range(0, n, NEIGHBOUR_BLOCK):
        hi = min(lo + NEIGHBOUR_BLOCK, n)
        d = np.array(dist[lo:hi], dtype=np.float64)
        rows = np.arange(hi - lo)
        d[rows, rows + lo] = np.inf
        nn = np.argpartition(d, k - 1, axis=1)[:, :k]
        order = np.argsort(d[rows[:, None], nn], axis=1, kind="stable")
        out[lo:hi] = nn[rows[:, None], order]
    return out


@njit(cache=True, nogil=True)
def _node(routes, sizes, r, p):  # type: ignore[no-untyped-def]
    """Route r's node at position p; -1 before the first task, -2 after the last. (Read
    first, then picked, as :func:`planner.operators.leg` is, for its speed.)"""
    return _pick_node(p, sizes[r], routes[r, min(max(p, 0), routes.shape[1] - 1)])


@njit(cache=True, nogil=True)
def _pick_node(p, size, task):  # type: ignore[no-untyped-def]
    """:func:`_node`'s answer from the route's size and the task read."""
    if p < 0:
        return -1
    if p >= size:
        return -2
    return task


@njit(cache=True, nogil=True)
def improve_allocation(  # type: ignore[no-untyped-def]
    perm, counts, objective, tables, neighbours, min_count, max_passes, pins, deadline=np.inf
):
    """Relocate and exchange tasks between routes while it pays; then 2-opt each route.
    Works in place on the chromosome and returns the number of moves applied. A pinned
    task (``pins``) is never moved, and nothing is put before it. Once ``deadline`` (a
    monotonic instant) has passed it stops, keeping the moves made, without the 2-opt."""
    dont_look = np.zeros(perm.shape[0], dtype=np.bool_)
    return allocation_search(
        perm, counts, objective, tables, neighbours, min_count, max_passes, pins, deadline,
        dont_look, False, RELOCATE | EXCHANGE, False,
    )  # fmt: skip


@njit(cache=True, nogil=True)
def allocation_search(  # type: ignore[no-untyped-def]
    perm,
    counts,
    objective,
    tables,
    neighbours,
    min_count,
    max_passes,
    pins,
    deadline,
    dont_look,
    use_bits,
    move_mask,
    lexi,
    cap=0.0,
):
    """:func:`improve_allocation`, with don't-look bits when ``use_bits``: a task whose
    bit is set is not looked at; a task in which no move pays gets its bit set, and a move
    clears the bits of the tasks around it (and, for the min-max objectives, of every task
    of the route that is then the longest). Starting with few bits clear (the tasks a
    perturbation moved) keeps the search local: O(moves), not O(n) a pass.

    ``move_mask`` is the mask of the moves tried (:mod:`planner.moves`). With ``lexi``, the
    total distance is a second objective, compared lexicographically after the
    objective's own figure: a move that leaves the figure as it is (the longest route of
    a min-max objective untouched) but shortens the fleet's total distance is taken.
    ``cap`` (min-max objectives; 0: none): the figure counts as at least ``cap``
    (:func:`planner.cost.fleet_value`), so a move may lengthen any route up to it when
    it shortens the fleet's total distance; a ``cap`` < 0 is the squeeze's figure instead,
    with the target ``-cap`` (:func:`planner.cost.squeeze_figure`)."""
    dist, start_dist, end_dist, road_h, road_f, task_h, task_f, ready, weights = tables
    m = counts.shape[0]
    n = perm.shape[0]
    task_x = task_f if objective == 2 else task_h
    use_extra = objective == 1 or objective == 2 or objective == 3
    routes = np.empty((m, n), dtype=np.int64)
    sizes = np.zeros(m, dtype=np.int64)
    route_of = np.empty(n, dtype=np.int64)
    pos = np.empty(n, dtype=np.int64)
    begin = 0
    for r in range(m):
        for k in range(counts[r]):
            t = perm[begin + k]
            routes[r, k] = t
            route_of[t] = r
            pos[t] = k
        sizes[r] = counts[r]
        begin += counts[r]
    lengths = np.zeros(m)
    extras = np.zeros(m)
    values = np.zeros(m)
    for r in range(m):
        s = 0.0
        prev = -1
        for k in range(sizes[r]):
            s += leg(prev, routes[r, k], r, dist, start_dist, end_dist)
            prev = routes[r, k]
            if use_extra:
                extras[r] += task_x[r, prev]
        s += leg(prev, -2, r, dist, start_dist, end_dist)
        lengths[r] = s
        values[r] = _route_value(objective, r, s, extras[r], road_h, road_f, ready, sizes[r])
    pref = np.zeros((m, n))
    for r in range(m):
        prefix(routes, sizes, r, r, dist, start_dist, pref)
    buf = np.empty(n, dtype=np.int64)
    current = _objective(objective, values, lengths, cap, weights)
    total = lengths.sum()
    top = np.empty(3, dtype=np.int64)  # the three longest routes: a move priced in O(1)
    largest_three(values, top)
    moves = 0
    late = False
    for _ in range(max_passes):
        improved = False
        for t in range(n):
            if t % CHECK_EVERY == 0 and past(deadline):
                late = True
                break
            if pins[t] >= 0 or (use_bits and dont_look[t]):
                continue
            a = route_of[t]
            pa = pos[t]
            prev_t = _node(routes, sizes, a, pa - 1)
            next_t = _node(routes, sizes, a, pa + 1)
            removal = (
                leg(prev_t, next_t, a, dist, start_dist, end_dist)
                - leg(prev_t, t, a, dist, start_dist, end_dist)
                - leg(t, next_t, a, dist, start_dist, end_dist)
            )
            eps = 1e-9 * max(1.0, abs(current))
            # Best gain so far in the objective's figure and (with lexi) in total distance.
            best_gain = 0.0 if lexi else eps
            best_gs = 1e-9 * max(1.0, total)
            best_var = 0
            best_kind = -1
            best_b = -1
            best_p = -1
            best_w = -1
            for q in range(neighbours.shape[1]):
                w = neighbours[t, q]
                b = route_of[w]
                if b == a:
                    continue
                pw = pos[w]
                # Relocate t next to w (before: between pw-1 and pw; after: pw and pw+1).
                if sizes[a] > min_count and move_mask & RELOCATE:
                    for side in range(2):
                        if side == 0 and pins[w] >= 0:
                            continue  # nothing goes before a pinned task
                        u = _node(routes, sizes, b, pw - 1 + side)
                        v = _node(routes, sizes, b, pw + side)
                        insertion = (
                            leg(u, t, b, dist, start_dist, end_dist)
                            + leg(t, v, b, dist, start_dist, end_dist)
                            - leg(u, v, b, dist, start_dist, end_dist)
                        )
                        la = lengths[a] + removal
                        lb = lengths[b] + insertion
                        ea = extras[a] - (task_x[a, t] if use_extra else 0.0)
                        eb = extras[b] + (task_x[b, t] if use_extra else 0.0)
                        va = _route_value(objective, a, la, ea, road_h, road_f, ready, sizes[a] - 1)
                        vb = _route_value(objective, b, lb, eb, road_h, road_f, ready, sizes[b] + 1)
                        gain = fleet_gain(
                            objective, values, lengths, cap, weights, top, a, va, la, b, vb, lb
                        )
                        gs = -removal - insertion
                        if _better(gain, gs, best_gain, best_gs, eps, lexi):
                            best_gain, best_gs = gain, gs
                            best_kind, best_b, best_p, best_w = 0, b, pw + side, w
                if move_mask & SEGMENT_RELOCATE:
                    for side in range(2):
                        if side == 0 and pins[w] >= 0:
                            continue  # nothing goes before a pinned task
                        for length in range(2, SEGMENT + 1):
                            if pa + length > sizes[a] or sizes[a] - length < min_count:
                                break
                            ea, eb = extras[a], extras[b]
                            if use_extra:
                                for k in range(pa, pa + length):
                                    ea -= task_x[a, routes[a, k]]
                                    eb += task_x[b, routes[a, k]]
                            for rev in range(2):
                                la, lb = segment_lengths(
                                    routes, sizes, pref, lengths, a, pa, length, b, pw + side,
                                    rev == 1, dist, start_dist, end_dist,
                                )  # fmt: skip
                                va = _route_value(
                                    objective, a, la, ea, road_h, road_f, ready, sizes[a] - length
                                )
                                vb = _route_value(
                                    objective, b, lb, eb, road_h, road_f, ready, sizes[b] + length
                                )
                                gain = fleet_gain(
                                    objective, values, lengths, cap, weights, top, a, va, la, b,
                                    vb, lb,
                                )  # fmt: skip
                                gs = lengths[a] + lengths[b] - la - lb
                                if _better(gain, gs, best_gain, best_gs, eps, lexi):
                                    best_gain, best_gs = gain, gs
                                    best_kind, best_b, best_p, best_w = 3, b, pw + side, w
                                    best_var = length * 2 + rev
                if move_mask & TWO_OPT_STAR:
                    for var in range(2):
                        if not two_opt_star_allowed(
                            routes, sizes, pins, a, pa, b, pw, var, min_count
                        ):
                            continue
                        la, lb = two_opt_star_lengths(
                            routes, sizes, pref, a, pa, b, pw, var, dist, start_dist, end_dist
                        )
                        na, nb = two_opt_star_sizes(sizes, a, pa, b, pw, var)
                        ea, eb = 0.0, 0.0
                        if use_extra:
                            ea, eb = _star_extras(routes, sizes, a, pa, b, pw, var, task_x)
                        va = _route_value(objective, a, la, ea, road_h, road_f, ready, na)
                        vb = _route_value(objective, b, lb, eb, road_h, road_f, ready, nb)
                        gain = fleet_gain(
                            objective, values, lengths, cap, weights, top, a, va, la, b, vb, lb
                        )
                        gs = lengths[a] + lengths[b] - la - lb
                        if _better(gain, gs, best_gain, best_gs, eps, lexi):
                            best_gain, best_gs = gain, gs
                            best_kind, best_b, best_p, best_w, best_var = 2, b, pw, w, var
                # Exchange t and w.
                if pins[w] >= 0 or not move_mask & EXCHANGE:
                    continue
                prev_w = _node(routes, sizes, b, pw - 1)
                next_w = _node(routes, sizes, b, pw + 1)
                da = (
                    leg(prev_t, w, a, dist, start_dist, end_dist)
                    + leg(w, next_t, a, dist, start_dist, end_dist)
                    - leg(prev_t, t, a, dist, start_dist, end_dist)
                    - leg(t, next_t, a, dist, start_dist, end_dist)
                )
                db = (
                    leg(prev_w, t, b, dist, start_dist, end_dist)
                    + leg(t, next_w, b, dist, start_dist, end_dist)
                    - leg(prev_w, w, b, dist, start_dist, end_dist)
                    - leg(w, next_w, b, dist, start_dist, end_dist)
                )
                la = lengths[a] + da
                lb = lengths[b] + db
                ea = extras[a] + ((task_x[a, w] - task_x[a, t]) if use_extra else 0.0)
                eb = extras[b] + ((task_x[b, t] - task_x[b, w]) if use_extra else 0.0)
                va = _route_value(objective, a, la, ea, road_h, road_f, ready, sizes[a])
                vb = _route_value(objective, b, lb, eb, road_h, road_f, ready, sizes[b])
                gain = fleet_gain(
                    objective, values, lengths, cap, weights, top, a, va, la, b, vb, lb
                )
                gs = -da - db
                if _better(gain, gs, best_gain, best_gs, eps, lexi):
                    best_gain, best_gs = gain, gs
                    best_kind, best_b, best_p, best_w = 1, b, pw, w
            if best_kind < 0:
                if use_bits:
                    dont_look[t] = True
                continue
            b = best_b
            if use_bits:
                _wake(dont_look, routes, sizes, a, pa)
                _wake(dont_look, routes, sizes, b, pos[best_w])
                dont_look[best_w] = False
            if best_kind == 2 or best_kind == 3:
                if best_kind == 2:
                    old_a = sizes[a]
                    two_opt_star_apply(
                        routes, sizes, pos, route_of, a, pa, b, best_p, best_var, buf
                    )
                    seam = best_p if best_var == 0 else old_a - pa - 1
                    ends = (pa + 1, seam - 1, seam)
                else:
                    length = best_var // 2
                    segment_apply(
                        routes, sizes, pos, route_of, a, pa, length, b, best_p,
                        best_var % 2 == 1, buf,
                    )  # fmt: skip
                    ends = (pa, best_p - 1, best_p + length)
                if use_bits:
                    _wake(dont_look, routes, sizes, a, ends[0])
                    _wake(dont_look, routes, sizes, b, ends[1])
                    _wake(dont_look, routes, sizes, b, ends[2])
                for r in (a, b):
                    s = 0.0
                    prev = -1
                    extras[r] = 0.0
                    for k in range(sizes[r]):
                        s += leg(prev, routes[r, k], r, dist, start_dist, end_dist)
                        prev = routes[r, k]
                        if use_extra:
                            extras[r] += task_x[r, prev]
                    lengths[r] = s + leg(prev, -2, r, dist, start_dist, end_dist)
            elif best_kind == 0:
                # Remove t from a.
                for k in range(pa, sizes[a] - 1):
                    routes[a, k] = routes[a, k + 1]
                    pos[routes[a, k]] = k
                sizes[a] -= 1
                lengths[a] += removal
                # Insert t into b at best_p.
                for k in range(sizes[b], best_p, -1):
                    routes[b, k] = routes[b, k - 1]
                    pos[routes[b, k]] = k
                routes[b, best_p] = t
                pos[t] = best_p
                route_of[t] = b
                sizes[b] += 1
                u = _node(routes, sizes, b, best_p - 1)
                v = _node(routes, sizes, b, best_p + 1)
                lengths[b] += (
                    leg(u, t, b, dist, start_dist, end_dist)
                    + leg(t, v, b, dist, start_dist, end_dist)
                    - leg(u, v, b, dist, start_dist, end_dist)
                )
                if use_extra:
                    extras[a] -= task_x[a, t]
                    extras[b] += task_x[b, t]
            else:
                w = best_w
                pw = pos[w]
                routes[a, pa] = w
                routes[b, pw] = t
                pos[w], pos[t] = pa, pw
                route_of[w], route_of[t] = a, b
                # Recompute both lengths exactly from their neighbours.
                for r in (a, b):
                    s = 0.0
                    prev = -1
                    for k in range(sizes[r]):
                        s += leg(prev, routes[r, k], r, dist, start_dist, end_dist)
                        prev = routes[r, k]
                    lengths[r] = s + leg(prev, -2, r, dist, start_dist, end_dist)
                if use_extra:
                    extras[a] += task_x[a, w] - task_x[a, t]
                    extras[b] += task_x[b, t] - task_x[b, w]
            values[a] = _route_value(
                objective, a, lengths[a], extras[a], road_h, road_f, ready, sizes[a]
            )
            values[b] = _route_value(
                objective, b, lengths[b], extras[b], road_h, road_f, ready, sizes[b]
            )
            prefix(routes, sizes, a, a, dist, start_dist, pref)
            prefix(routes, sizes, b, b, dist, start_dist, pref)
            largest_three(values, top)
            current = _objective(objective, values, lengths, cap, weights)
            total = lengths.sum()
            if use_bits and (objective == 3 or objective == 4):
                longest = np.argmax(values)
                for k in range(sizes[longest]):
                    dont_look[routes[longest, k]] = False
            moves += 1
            improved = True
        if late or not improved:
            break
    rows_back(routes, sizes, perm, counts)
    if not late:
        improve_routes(perm, counts, dist, start_dist, end_dist, neighbours, pins)
    return moves


@njit(cache=True, nogil=True)
def _better(gain, gs, best_gain, best_gs, eps, lexi):  # type: ignore[no-untyped-def]
    """Whether a move of ``gain`` in the objective and ``gs`` in total distance beats the
    best so far: by its gain, or (with ``lexi``) by its distance at no smaller gain."""
    if not lexi:
        return gain > best_gain
    return gain > best_gain + eps or (gain >= best_gain and gs > best_gs)


@njit(cache=True, nogil=True)
def _star_extras(routes, sizes, a, pa, b, pw, variant, task_x):  # type: ignore[no-untyped-def]
    """The in-field figures (``task_x`` per machine) of routes a and b after the 2-opt*
    move (:func:`planner.moves.two_opt_star_lengths`): O(route lengths)."""
    ea = 0.0
    eb = 0.0
    for k in range(pa + 1):
        ea += task_x[a, routes[a, k]]
    for k in range(pa + 1, sizes[a]):
        eb += task_x[b, routes[a, k]]
    lo, hi = (pw, sizes[b]) if variant == 0 else (0, pw + 1)
    for k in range(sizes[b]):
        if lo <= k < hi:
            ea += task_x[a, routes[b, k]]
        else:
            eb += task_x[b, routes[b, k]]
    return ea, eb


@njit(cache=True, nogil=True)
def _wake(dont_look, routes, sizes, r, p):  # type: ignore[no-untyped-def]
    """Clear the don't-look bits of route r's tasks at places p-1..p+1."""
    for k in range(max(p - 1, 0), min(p + 2, sizes[r])):
        dont_look[routes[r, k]] = False


@njit(cache=True, nogil=True)
def optimal_split(perm, counts, objective, tables, min_count, pins, deadline=np.inf):  # type: ignore[no-untyped-def]
    """Re-cut the task order into routes optimally for the objective (Prins's Split,
    with machine k taking the k-th stretch): dynamic programming over how many tasks the
    first k machines take, O(m n^2). Changes ``counts`` only; returns the new cost
    without the min-max tie-breaker. With pins, a machine's stretch starts with its pinned
    task and holds no other; when the order allows no such cut, or ``deadline`` (a
    monotonic instant) passes before the cut is found, ``counts`` is kept and the return
    is infinite."""
    dist, start_dist, end_dist, road_h, road_f, task_h, task_f, ready, _ = tables
    n = perm.shape[0]
    m = counts.shape[0]
    use_max = objective == 3 or objective == 4
    prefix = np.zeros(n)
    for t in range(1, n):
        prefix[t] = prefix[t - 1] + dist[perm[t - 1], perm[t]]
    task_x = task_f if objective == 2 else task_h
    use_extra = objective == 1 or objective == 2 or objective == 3
    extra = np.zeros((m, n + 1))
    if use_extra:
        for k in range(m):
            for t in range(n):
                extra[k, t + 1] = extra[k, t] + task_x[k, perm[t]]
    # Pinned tasks: where each machine's is in the order, and how many lie before a place.
    pin_at = np.full(m, -1, dtype=np.int64)
    pinned_before = np.zeros(n + 1, dtype=np.int64)
    for t in range(n):
        pinned_before[t + 1] = pinned_before[t]
        if pins[perm[t]] >= 0:
            pin_at[pins[perm[t]]] = t
            pinned_before[t + 1] += 1
    inf = np.inf
    best = np.full((m + 1, n + 1), inf)
    cut = np.zeros((m + 1, n + 1), dtype=np.int64)
    best[0, 0] = 0.0
    for k in range(1, m + 1):
        mk = k - 1
        rate = 1.0
        if objective == 1 or objective == 3:
            rate = road_h[mk]
        elif objective == 2:
            rate = road_h[mk] * road_f[mk]
        # Machine k takes tasks i..j-1; every later machine still needs min_count tasks.
        for j in range(k * min_count, n - (m - k) * min_count + 1):
            if j % CHECK_EVERY == 0 and past(deadline):
                return inf
            for i in range(max(0, (k - 1) * min_count), j - min_count + 1):
                before = best[k - 1, i]
                if before == inf:
                    continue
                if pin_at[mk] >= 0:
                    if j == i or i != pin_at[mk] or pinned_before[j] - pinned_before[i + 1] > 0:
                        continue
                elif pinned_before[j] - pinned_before[i] > 0:
                    continue
                if j == i:
                    value = 0.0
                else:
                    s = (
                        start_dist[mk, perm[i]]
                        + prefix[j - 1]
                        - prefix[i]
                        + end_dist[mk, perm[j - 1]]
                    )
                    value = s * rate + (extra[mk, j] - extra[mk, i])
                    if objective == 1 or objective == 3:
                        value += ready[mk]
                total = max(before, value) if use_max else before + value
                if total < best[k, j]:
                    best[k, j] = total
                    cut[k, j] = i
    if best[m, n] == inf:
        return inf
    j = n
    for k in range(m, 0, -1):
        i = cut[k, j]
        counts[k - 1] = j - i
        j = i
    return best[m, n]
