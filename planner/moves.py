"""Moves between routes for ``hybrid``'s local search, each with one contract: the route
lengths it would give (evaluated in O(1) from the routes' prefix lengths), and ``apply``.

The local search (:func:`planner.local_search.allocation_search`) keeps the chromosome as
route rows: ``routes[r, :sizes[r]]`` the tasks of machine r in driving order, and
``pref[r, k]`` the distance driven from r's start up to and including its k-th task
(:func:`prefix`). A move named in :data:`MOVES` is switched on by its bit in the
``moves`` mask (:func:`mask`); ``hybrid`` selects them by name (``HybridParams.moves``).

- ``relocate``: a task goes next to one of its nearest neighbours in another route;
- ``exchange``: a task and one of its nearest neighbours in another route swap places;
- ``two_opt_star``: 2-opt* (Potvin & Rousseau): two routes exchange their tails so that a
  task and one of its nearest neighbours in the other route become consecutive, as they
  are (variant 0: t's head, then w and the rest of w's route) or crosswise (variant 1:
  t's head, then w's head reversed; w's route gets t's tail reversed, then w's tail);
- ``segment_relocate`` (Or-opt between routes): 2..:data:`SEGMENT` consecutive tasks
  starting at a task go, as they are or reversed, next to one of its nearest neighbours
  in another route.

``relocate`` and ``exchange`` are evaluated and applied by the search itself (they were
there before this module); their bits let them be switched off like any other.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from planner.cost import fleet_value, route_value
from planner.operators import leg
from planner.rng import randint, shuffle

MOVES = ("relocate", "exchange", "two_opt_star", "segment_relocate")
# Bits of the ``moves`` mask, in MOVES' order.
RELOCATE, EXCHANGE, TWO_OPT_STAR, SEGMENT_RELOCATE = 1, 2, 4, 8
SEGMENT = 3  # segment_relocate moves 2..SEGMENT tasks


def mask(names: tuple[str, ...] | list[str]) -> int:
    """The ``moves`` bit mask of the moves named (each one of :data:`MOVES`)."""
    out = 0
    for name in names:
        if name not in MOVES:
            raise ValueError(f"unknown move {name!r}; choose among {', '.join(MOVES)}")
        out |= 1 << MOVES.index(name)
    return out


@njit(cache=True, nogil=True)
def prefix(routes, sizes, r, machine, dist, start_dist, pref):  # type: ignore[no-untyped-def]
    """Fill ``pref[r, :sizes[r]]``: the distance from the start to each task of route r."""
    s = 0.0
    prev = -1
    for k in range(sizes[r]):
        t = routes[r, k]
        s += leg(prev, t, machine, dist, start_dist, start_dist)
        pref[r, k] = s
        prev = t


@njit(cache=True, nogil=True)
def _inner(pref, r, i, j):  # type: ignore[no-untyped-def]
    """Distance along route r from its i-th to its j-th task (0 when i >= j)."""
    if i >= j:
        return 0.0
    return pref[r, j] - pref[r, i]


@njit(cache=True, nogil=True)
def two_opt_star_lengths(  # type: ignore[no-untyped-def]
    routes, sizes, pref, a, pa, b, pw, variant, dist, start_dist, end_dist
):
    """The lengths of routes a and b after :func:`two_opt_star_apply` with the same
    arguments, in O(1): t = routes[a, pa] keeps a's head up to it and is then followed
    by w = routes[b, pw]. Variant 0: a = a[:pa+1] + b[pw:], b = b[:pw] + a[pa+1:].
    Variant 1: a = a[:pa+1] + reversed(b[:pw+1]), b = reversed(a[pa+1:]) + b[pw+1:].
    Assumes ``dist`` symmetric (the reversed stretches keep their length)."""
    sa, sb = sizes[a], sizes[b]
    t, w = routes[a, pa], routes[b, pw]
    a_last, b_last = routes[a, sa - 1], routes[b, sb - 1]
    head_a = pref[a, pa]
    tail_a = pa + 1 < sa  # a has tasks after t
    if variant == 0:
        new_a = head_a + dist[t, w] + _inner(pref, b, pw, sb - 1) + end_dist[a, b_last]
        if pw == 0 and not tail_a:
            new_b = 0.0
        elif not tail_a:
            new_b = pref[b, pw - 1] + end_dist[b, routes[b, pw - 1]]
        else:
            first = routes[a, pa + 1]
            into = (
                start_dist[b, first]
                if pw == 0
                else pref[b, pw - 1] + dist[routes[b, pw - 1], first]
            )
            new_b = into + _inner(pref, a, pa + 1, sa - 1) + end_dist[b, a_last]
        return new_a, new_b
    b_first = routes[b, 0]
    new_a = head_a + dist[t, w] + _inner(pref, b, 0, pw) + end_dist[a, b_first]
    tail_b = pw + 1 < sb
    if not tail_a and not tail_b:
        new_b = 0.0
    elif not tail_a:
        new_b = start_dist[b, routes[b, pw + 1]] + _inner(pref, b, pw + 1, sb - 1)
        new_b += end_dist[b, b_last]
    else:
        first = routes[a, pa + 1]
        new_b = start_dist[b, a_last] + _inner(pref, a, pa + 1, sa - 1)
        if tail_b:
            new_b += dist[first, routes[b, pw + 1]] + _inner(pref, b, pw + 1, sb - 1)
            new_b += end_dist[b, b_last]
        else:
            new_b += end_dist[b, first]
    return new_a, new_b


@njit(cache=True, nogil=True)
def two_opt_star_sizes(sizes, a, pa, b, pw, variant):  # type: ignore[no-untyped-def]
    """How many tasks routes a and b have after the move."""
    if variant == 0:
        return pa + 1 + sizes[b] - pw, pw + sizes[a] - pa - 1
    return pa + 1 + pw + 1, sizes[a] - pa - 1 + sizes[b] - pw - 1


@njit(cache=True, nogil=True)
def two_opt_star_allowed(routes, sizes, pins, a, pa, b, pw, variant, min_count):  # type: ignore[no-untyped-def]
    """Whether the move keeps every route at ``min_count`` tasks or more and every pinned
    task (``pins``: always first in its route) first in its machine's route."""
    na, nb = two_opt_star_sizes(sizes, a, pa, b, pw, variant)
    if na < min_count or nb < min_count:
        return False
    if variant == 0:
        return not (pw == 0 and pins[routes[b, 0]] >= 0)
    return pins[routes[b, 0]] < 0


@njit(cache=True, nogil=True)
def two_opt_star_apply(routes, sizes, pos, route_of, a, pa, b, pw, variant, buf):  # type: ignore[no-untyped-def]
    """Apply the move (see :func:`two_opt_star_lengths`) to the route rows and the
    ``pos``/``route_of`` index of every task; ``buf`` is scratch of n ints."""
    sa, sb = sizes[a], sizes[b]
    na, nb = two_opt_star_sizes(sizes, a, pa, b, pw, variant)
    # New b into buf, new a in place (a's head stays).
    out = 0
    if variant == 0:
        for k in range(pw):
            buf[out] = routes[b, k]
            out += 1
        for k in range(pa + 1, sa):
            buf[out] = routes[a, k]
            out += 1
        for k in range(pw, sb):
            routes[a, pa + 1 + k - pw] = routes[b, k]
    else:
        for k in range(sa - 1, pa, -1):
            buf[out] = routes[a, k]
            out += 1
        for k in range(pw + 1, sb):
            buf[out] = routes[b, k]
            out += 1
        for k in range(pw + 1):
            routes[a, pa + 1 + k] = routes[b, pw - k]
    for k in range(nb):
        routes[b, k] = buf[k]
    sizes[a], sizes[b] = na, nb
    for r in (a, b):
        for k in range(sizes[r]):
            t = routes[r, k]
            pos[t] = k
            route_of[t] = r


@njit(cache=True, nogil=True)
def segment_lengths(  # type: ignore[no-untyped-def]
    routes, sizes, pref, lengths, a, pa, length, b, p, rev, dist, start_dist, end_dist
):
    """The lengths of routes a and b after :func:`segment_apply` with the same arguments,
    in O(1): routes[a, pa:pa+length] leave a and go into b before its p-th task (p =
    sizes[b]: at its end), reversed when ``rev``. Assumes ``dist`` symmetric."""
    s0 = routes[a, pa]
    s1 = routes[a, pa + length - 1]
    before = routes[a, pa - 1] if pa > 0 else -1
    after = routes[a, pa + length] if pa + length < sizes[a] else -2
    inner = pref[a, pa + length - 1] - pref[a, pa]
    new_a = (
        lengths[a]
        - leg(before, s0, a, dist, start_dist, end_dist)
        - inner
        - leg(s1, after, a, dist, start_dist, end_dist)
        + leg(before, after, a, dist, start_dist, end_dist)
    )
    u = routes[b, p - 1] if p > 0 else -1
    v = routes[b, p] if p < sizes[b] else -2
    first, last = (s1, s0) if rev else (s0, s1)
    new_b = (
        lengths[b]
        - leg(u, v, b, dist, start_dist, end_dist)
        + leg(u, first, b, dist, start_dist, end_dist)
        + inner
        + leg(last, v, b, dist, start_dist, end_dist)
    )
    return new_a, new_b


@njit(cache=True, nogil=True)
def segment_apply(routes, sizes, pos, route_of, a, pa, length, b, p, rev, buf):  # type: ignore[no-untyped-def]
    """Apply the move (see :func:`segment_lengths`) to the route rows and the
    ``pos``/``route_of`` index of every task; ``buf`` is scratch of n ints."""
    for k in range(length):
        buf[k] = routes[a, pa + length - 1 - k] if rev else routes[a, pa + k]
    for k in range(pa, sizes[a] - length):
        routes[a, k] = routes[a, k + length]
    sizes[a] -= length
    for k in range(sizes[b] - 1, p - 1, -1):
        routes[b, k + length] = routes[b, k]
    for k in range(length):
        routes[b, p + k] = buf[k]
    sizes[b] += length
    for r in (a, b):
        for k in range(sizes[r]):
            t = routes[r, k]
            pos[t] = k
            route_of[t] = r


@njit(cache=True, nogil=True)
def ruin_recreate(  # type: ignore[no-untyped-def]
    state,
    perm,
    counts,
    objective,
    tables,
    neighbours,
    size,
    focus_longest,
    min_count,
    pins,
    moved,
    cap=0.0,
):
    """Ruin and recreate (Schrimpf et al. 2000, radial ruin), the ILS's stronger
    perturbation: a seed task and its nearest neighbours, ``size`` tasks in all, leave
    their routes; then :func:`recreate` puts each back where the objective grows least
    (with ``cap`` > 0 a min-max figure counts as at least ``cap``: below it the distance
    decides; with ``cap`` < 0 the squeeze's figure: :func:`planner.cost.fleet_value`). With
    ``focus_longest`` the seed is taken from the route of highest share of the objective,
    the one that sets a min-max figure: its neighbourhood is re-cut between the routes
    around it. O(n m + size (n + m²)) on the chromosome in place. A route is never left
    below ``min_count`` and a pinned task never moves (nor has one put before it). The tasks
    moved are written to ``moved`` (the rest -1); returns how many."""
    n = perm.shape[0]
    m = counts.shape[0]
    moved[:] = -1
    routes, sizes = route_rows(perm, counts)
    route_of = np.empty(n, dtype=np.int64)
    for r in range(m):
        for k in range(sizes[r]):
            route_of[routes[r, k]] = r
    seed = randint(state, n)
    if focus_longest:
        task_x = tables[6] if objective == 2 else tables[5]
        use_extra = objective == 1 or objective == 2 or objective == 3
        values, lengths, extras = np.zeros(m), np.zeros(m), np.zeros(m)
        for r in range(m):
            _figures(
                routes, sizes, r, objective, tables, task_x, use_extra, lengths, extras, values
            )
        longest = int(np.argmax(values))
        if sizes[longest] > 0:
            seed = routes[longest, randint(state, sizes[longest])]
    left = sizes.copy()  # each route's size once the tasks chosen so far are out
    done = 0
    for q in range(-1, neighbours.shape[1]):
        if done >= size or done >= moved.shape[0]:
            break
        t = seed if q < 0 else neighbours[seed, q]
        r = route_of[t]
        if pins[t] >= 0 or left[r] <= min_count:
            continue
        left[r] -= 1
        moved[done] = t
        done += 1
    recreate(state, perm, counts, objective, tables, pins, moved[:done], cap)
    return done


@njit(cache=True, nogil=True)
def recreate(state, perm, counts, objective, tables, pins, tasks, cap=0.0):  # type: ignore[no-untyped-def]
    """Take ``tasks`` out of their routes, then put each back, in random order, at the
    place of any route where the objective grows least, ties (a min-max figure that the
    place leaves as it is, or that stays under ``cap`` > 0; ``cap`` < 0, the squeeze's
    figure: :func:`planner.cost.fleet_value`)
    broken by the distance it adds; never before a pinned task.
    The recreate half of :func:`ruin_recreate`, and the repair of a warm start whose
    tasks were not all in a route (a machine gone: its tasks go where they cost least).
    O(n m + len(tasks) (n + m²)), on the chromosome in place; the caller keeps the
    routes' minimum sizes and the pinned tasks out of ``tasks``."""
    dist, start_dist, end_dist, road_h, road_f, task_h, task_f, ready, weights = tables
    n = perm.shape[0]
    m = counts.shape[0]
    task_x = task_f if objective == 2 else task_h
    use_extra = objective == 1 or objective == 2 or objective == 3
    routes, sizes = route_rows(perm, counts)
    out = np.zeros(n, dtype=np.bool_)
    for t in tasks:
        out[t] = True
    for r in range(m):
        kept = 0
        for k in range(sizes[r]):
            if not out[routes[r, k]]:
                routes[r, kept] = routes[r, k]
                kept += 1
        sizes[r] = kept
    values = np.zeros(m)
    lengths = np.zeros(m)
    extras = np.zeros(m)
    for r in range(m):
        _figures(routes, sizes, r, objective, tables, task_x, use_extra, lengths, extras, values)
    order = tasks.copy()
    shuffle(state, order)
    for t in order:
        best_obj = np.inf
        best_add = np.inf
        best_r = -1
        best_p = -1
        for b in range(m):
            # The route's cheapest place: the fleet's figure never falls as the route
            # grows (fleet_value), so it is the route's best; the figure once a route.
            first = 1 if sizes[b] > 0 and pins[routes[b, 0]] >= 0 else 0
            add = np.inf
            at = -1
            for p in range(first, sizes[b] + 1):
                u = routes[b, p - 1] if p > 0 else -1
                v = routes[b, p] if p < sizes[b] else -2
                here = (
                    leg(u, t, b, dist, start_dist, end_dist)
                    + leg(t, v, b, dist, start_dist, end_dist)
                    - leg(u, v, b, dist, start_dist, end_dist)
                )
                if here < add:
                    add, at = here, p
            eb = extras[b] + (task_x[b, t] if use_extra else 0.0)
            old_value, old_length = values[b], lengths[b]
            lengths[b] = old_length + add
            values[b] = route_value(objective, b, lengths[b], eb, road_h, road_f, ready, 1)
            value = fleet_value(objective, values, lengths, cap, weights)
            values[b], lengths[b] = old_value, old_length
            eps = 1e-9 * max(1.0, abs(value))
            if value < best_obj - eps or (value <= best_obj + eps and add < best_add):
                best_obj, best_add, best_r, best_p = value, add, b, at
        for j in range(sizes[best_r], best_p, -1):
            routes[best_r, j] = routes[best_r, j - 1]
        routes[best_r, best_p] = t
        sizes[best_r] += 1
        _figures(
            routes, sizes, best_r, objective, tables, task_x, use_extra, lengths, extras, values
        )
    rows_back(routes, sizes, perm, counts)


@njit(cache=True, nogil=True)
def route_rows(perm, counts):  # type: ignore[no-untyped-def]
    """The chromosome as route rows: ``routes[r, :sizes[r]]`` machine r's tasks in order."""
    m, n = counts.shape[0], perm.shape[0]
    routes = np.zeros((m, n), dtype=np.int64)
    sizes = np.zeros(m, dtype=np.int64)
    begin = 0
    for r in range(m):
        for k in range(counts[r]):
            routes[r, k] = perm[begin + k]
        sizes[r] = counts[r]
        begin += counts[r]
    return routes, sizes


@njit(cache=True, nogil=True)
def rows_back(routes, sizes, perm, counts):  # type: ignore[no-untyped-def]
    """Write route rows back into the chromosome ``perm``/``counts`` (in place)."""
    begin = 0
    for r in range(sizes.shape[0]):
        for k in range(sizes[r]):
            perm[begin + k] = routes[r, k]
        counts[r] = sizes[r]
        begin += sizes[r]


@njit(cache=True, nogil=True)
def _figures(routes, sizes, r, objective, tables, task_x, use_extra, lengths, extras, values):  # type: ignore[no-untyped-def]
    """Route r's distance, in-field figure and share of the objective, into the arrays."""
    dist, start_dist, end_dist, road_h, road_f, _, _, ready, _ = tables
    s = 0.0
    e = 0.0
    prev = -1
    for k in range(sizes[r]):
        t = routes[r, k]
        s += leg(prev, t, r, dist, start_dist, end_dist)
        if use_extra:
            e += task_x[r, t]
        prev = t
    s += leg(prev, -2, r, dist, start_dist, end_dist)
    lengths[r] = s
    extras[r] = e
    values[r] = route_value(objective, r, s, e, road_h, road_f, ready, sizes[r])
