"""The cyclic exchange: one task out of each route and back into another, all routes at once.

Under the makespan the plan is jammed: every route ends within minutes of the makespan, so
a relocate or a swap between two routes that shortens the roads lengthens one of them past
the cap. A cyclic exchange moves one task from route a to b, one from b to c, ..., one from
the last back to a: each route loses one task and gains one, so its hours change by the
difference of the two, and a chain of three or more routes can shorten the roads where
every pair is stuck (the cyclic transfers of Thompson and Psaraftis, 1993, for vehicle
routing; Ahuja et al.'s very large-scale neighbourhoods).

One round picks one task at random in each route (not a pinned one). The cost of route i
taking route a's task, in place of its own, at the best place in what is left of it, is
route i's new figure, or a big number if its new hours would exceed the cap; the cost of
keeping its own is its figure now. The figure is the route's road distance, or, given a
``target``, its term of the squeeze (:func:`planner.cost.squeeze_term`: its hours weighed by
its machine's worth to the makespan, each hour after the target counted many times) with
its hours of driving counted ``road_weight`` times more, so that the fields go where the
fleet does them in fewer weighed hours, but not for road that buys little. The cheapest way
of giving each route one of the picked tasks is an assignment problem over the routes, solved
exactly (:func:`assignment`), and it is applied when it lowers the figures' sum: so a round
finds the best exchange of the picked tasks along any set of disjoint cycles, and never
takes a route above the cap. O(m^2 x route length + m^3) a round, m routes.

Paths too (the ejection chains of Glover, 1996): a route's pick may be no task at all. A
route that picks nothing gives nothing and may take a task without losing one; a route
given another's empty pick takes nothing and only loses its own. A cycle through an empty
pick is then a path: route a's task to b, b's to c, ..., and the route at the path's start
one task the lighter, the one at its end one heavier. So the exchange also moves a field
from a full route towards one with room along a chain, where no single move fits.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from planner.choices import Objective
from planner.cost import route_distance, route_value, squeeze_term
from planner.local_search import past
from planner.operators import leg
from planner.rng import randint, uniform

INFEASIBLE = 1e15  # the cost of a route over the cap (metres; far above any road)
_MAKESPAN = int(Objective.MAKESPAN)  # the route figure the cap bounds: hours


@njit(cache=True, nogil=True)
def assignment(costs):  # type: ignore[no-untyped-def]
    """The rows' columns (a permutation) of least total cost in the square matrix
    ``costs``: shortest augmenting paths with potentials (the Hungarian method in its
    O(n^3) form)."""
    n = costs.shape[0]
    u = np.zeros(n + 1)
    v = np.zeros(n + 1)
    row_of = np.zeros(n + 1, dtype=np.int64)  # column j's row (1-based; 0: none)
    way = np.zeros(n + 1, dtype=np.int64)
    for i in range(1, n + 1):
        row_of[0] = i
        j0 = 0
        minv = np.full(n + 1, np.inf)
        used = np.zeros(n + 1, dtype=np.bool_)
        while True:
            used[j0] = True
            i0 = row_of[j0]
            delta = np.inf
            j1 = 0
            for j in range(1, n + 1):
                if not used[j]:
                    cur = costs[i0 - 1, j - 1] - u[i0] - v[j]
                    if cur < minv[j]:
                        minv[j] = cur
                        way[j] = j0
                    if minv[j] < delta:
                        delta = minv[j]
                        j1 = j
            for j in range(n + 1):
                if used[j]:
                    u[row_of[j]] += delta
                    v[j] -= delta
                else:
                    minv[j] -= delta
            j0 = j1
            if row_of[j0] == 0:
                break
        while j0 != 0:
            j1 = way[j0]
            row_of[j0] = row_of[j1]
            j0 = j1
    out = np.empty(n, dtype=np.int64)
    for j in range(1, n + 1):
        out[row_of[j] - 1] = j - 1
    return out


@njit(cache=True, nogil=True)
def _squeezed(hours, driving, target, weight, road_weight):  # type: ignore[no-untyped-def]
    """A route's figure under the squeeze: its term of the squeeze's figure and its
    ``driving`` hours weighed ``road_weight`` times more."""
    return squeeze_term(hours, target, weight) + road_weight * weight * driving


@njit(cache=True, nogil=True)
def cyclic_exchange(
    state,
    perm,
    counts,
    tables,
    pins,
    cap,
    rounds,
    deadline=np.inf,
    target=0.0,
    road_weight=0.0,
    empty_share=0.0,
    min_count=0,
):  # type: ignore[no-untyped-def]
    """``rounds`` rounds of the cyclic exchange (see the module) on the chromosome
    ``perm``/``counts`` in place, under the makespan: no route's hours (its ready time,
    service and driving, :func:`planner.cost.route_value`) above ``cap``, or above its hours
    when the call began if it was above the cap then. With ``empty_share`` 0 the routes keep
    their number of tasks; otherwise each route's pick is no task with that chance (always
    for an empty route), and the routes' sizes change along paths, none below
    ``min_count``. A pinned task neither moves nor has a task put before it. Stops early
    once ``deadline`` (a monotonic instant) has passed. Returns the road saved (metres);
    given a ``target`` > 0, the squeeze's figure lowered instead: the sum over the routes of
    :func:`planner.cost.squeeze_term` (with the tables' hour weights) and of their weighed
    hours of driving times ``road_weight``."""
    dist, start_dist, end_dist, road_h, road_f, task_hours, _, ready, weights = tables
    m = counts.shape[0]
    begin = np.zeros(m, dtype=np.int64)  # where each route starts in perm, this round
    hours = np.zeros(m)
    road = np.zeros(m)
    pick = np.full(m, -1, dtype=np.int64)  # the picked task's place in perm; -1: none
    empty = np.zeros(m, dtype=np.bool_)  # the route's pick is no task (gives nothing)
    left_hours = np.zeros(m)  # route i without its pick, taking a task (busy)
    gone_hours = np.zeros(m)  # route i without its pick, taking nothing
    gone_road = np.zeros(m)
    left_road = np.zeros(m)
    costs = np.empty((m, m))
    place = np.empty((m, m), dtype=np.int64)  # put route a's task before perm[place]
    out = np.empty_like(perm)
    new_counts = np.empty_like(counts)
    # Each route's ceiling: the cap, or its hours when the call began if above it (taken
    # from then, not round by round, so that no route creeps past it a rounding at a time).
    ceiling = np.full(m, np.nan)
    saved = 0.0
    for _ in range(rounds):
        if past(deadline):
            break
        begin[0] = 0
        for i in range(1, m):
            begin[i] = begin[i - 1] + counts[i - 1]
        for i in range(m):
            pick[i] = -1
            empty[i] = False
            c = counts[i]
            b = begin[i]
            service = 0.0
            for k in range(b, b + c):
                service += task_hours[i, perm[k]]
            road[i] = route_distance(perm, b, c, i, dist, start_dist, end_dist)
            hours[i] = route_value(_MAKESPAN, i, road[i], service, road_h, road_f, ready, c)
            if np.isnan(ceiling[i]):
                ceiling[i] = max(cap, hours[i])
            if empty_share > 0.0 and (c == 0 or uniform(state) < empty_share):
                empty[i] = True  # gives nothing; may take a task (then one more)
                left_road[i] = road[i]
                left_hours[i] = route_value(
                    _MAKESPAN, i, road[i], service, road_h, road_f, ready, c + 1
                )
                gone_hours[i] = hours[i]
                gone_road[i] = road[i]
                continue
            if c == 0:
                continue  # without empty picks an empty route stays out
            q = b + randint(state, c)
            t = perm[q]
            if pins[t] >= 0:
                continue
            pick[i] = q
            prev = perm[q - 1] if q > b else -1
            nxt = perm[q + 1] if q < b + c - 1 else -2
            left_road[i] = (
                road[i]
                + leg(prev, nxt, i, dist, start_dist, end_dist)
                - leg(prev, t, i, dist, start_dist, end_dist)
                - leg(t, nxt, i, dist, start_dist, end_dist)
            )
            left_hours[i] = route_value(
                _MAKESPAN, i, left_road[i], service - task_hours[i, t], road_h, road_f, ready, c
            )
            gone_road[i] = left_road[i] if c > 1 else 0.0
            gone_hours[i] = route_value(
                _MAKESPAN, i, gone_road[i], service - task_hours[i, t], road_h, road_f, ready, c - 1
            )
        base = 0.0
        for i in range(m):
            own = road[i]
            if target > 0.0:
                own = _squeezed(hours[i], road[i] * road_h[i], target, weights[i], road_weight)
            base += own
            for a in range(m):
                costs[i, a] = INFEASIBLE
            costs[i, i] = own
            if pick[i] < 0 and not empty[i]:
                continue
            limit = ceiling[i]
            b = begin[i]
            c = counts[i]
            for a in range(m):
                if a == i or (pick[a] < 0 and not empty[a]):
                    continue
                if empty[a]:
                    # route i takes nothing: loses its pick, or stays as it is
                    if empty[i]:
                        costs[i, a] = own
                    elif c - 1 >= min_count and gone_hours[i] <= limit + 1e-9:
                        if target <= 0.0:
                            costs[i, a] = gone_road[i]
                        else:
                            costs[i, a] = _squeezed(
                                gone_hours[i], gone_road[i] * road_h[i], target, weights[i],
                                road_weight,
                            )  # fmt: skip
                    continue
                x = perm[pick[a]]
                best = np.inf
                best_at = -1
                prev = -1  # the start
                for k in range(b, b + c + 1):
                    if k == pick[i]:
                        continue
                    nxt = perm[k] if k < b + c else -2
                    if prev == -1 and nxt >= 0 and pins[nxt] >= 0:
                        prev = nxt  # nothing goes before a pinned first task
                        continue
                    delta = (
                        leg(prev, x, i, dist, start_dist, end_dist)
                        + leg(x, nxt, i, dist, start_dist, end_dist)
                        - leg(prev, nxt, i, dist, start_dist, end_dist)
                    )
                    if delta < best:
                        best = delta
                        best_at = k
                    if k < b + c:
                        prev = perm[k]
                if best_at < 0:
                    continue
                # route_value's hours, from left_hours by the delta (i's service without its
                # pick is in left_hours already).
                h = left_hours[i] + task_hours[i, x] + best * road_h[i]
                if h <= limit + 1e-9:
                    if target <= 0.0:
                        costs[i, a] = left_road[i] + best
                    else:
                        costs[i, a] = _squeezed(
                            h, (left_road[i] + best) * road_h[i], target, weights[i], road_weight
                        )
                    place[i, a] = best_at
        given = assignment(costs)
        total = 0.0
        for i in range(m):
            total += costs[i, given[i]]
        if not total < base - (1e-6 if target <= 0.0 else 1e-7):  # metres; weighed hours
            continue
        saved += base - total
        o = 0
        for i in range(m):
            a = given[i]
            b = begin[i]
            c = counts[i]
            n_i = c
            takes = a != i and not empty[a]
            gives = a != i and not empty[i]
            for k in range(b, b + c + 1):
                if takes and k == place[i, a]:
                    out[o] = perm[pick[a]]
                    o += 1
                if k < b + c and not (gives and k == pick[i]):
                    out[o] = perm[k]
                    o += 1
            if takes:
                n_i += 1
            if gives:
                n_i -= 1
            new_counts[i] = n_i
        perm[:] = out
        counts[:] = new_counts
    return saved
