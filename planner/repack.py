"""Re-packing neighbouring routes: the fields of two (or a few) routes that lie side by side
shared out among their machines again, as a small assignment solved exactly.

Under the makespan the squeeze (:func:`planner.cost.squeeze_figure`: the machines' hours
weighed by what they are worth to the makespan, each hour past a target counted
:data:`~planner.cost.OVERLOAD` times more) is walked by moves of one field, two swapped,
or one handed round a cycle of routes. Where every route ends near the target a field
moved in is a field too many, and a better packing of two routes — two small fields for
a large one, three for two — is out of their reach.

Here a group's routes are priced as linear in their fields: a field a route keeps costs
its service on that machine and what leaving it out would save of the road; a field it
would take, its service and its cheapest insertion. Under that model the best share of
the group's fields among its machines by the squeeze's figure, no route past ``limit`` and
none under ``min_count`` fields, is an integer program of |group| × |fields| binaries and
|group| overloads (HiGHS' branch and bound through :func:`scipy.optimize.milp`, a node
limit so that the same seed gives the same answer: ~10 ms for two routes of a 500 × 30
farm). The routes are then rebuilt — the fields a route keeps in their order, the ones
it takes each at its cheapest place, the farthest first, then 2-opt — and the result is
kept only if the squeeze's exact figure falls and no route ends past ``limit``: the
linear model proposes, the route costs decide.

A group is the route of a random field and ``size - 1`` routes drawn among those its
fields' nearest neighbours lie on. Pinned fields stay first on their machines. This is the
exact sub-problem solve of the decomposition methods for routing (the "assign, then
route" of Fisher and Jaikumar, 1981, applied to a few routes at a time, as in the
POPMUSIC matheuristics of Taillard and Voß).
"""

from __future__ import annotations

import time

import numpy as np

from planner.cost import OVERLOAD, evaluate, squeeze_figure
from planner.operators import improve_routes
from planner.rng import randint

# HiGHS' branch-and-bound nodes for one group; a group is small and its optimum is found in
# a few, and a node limit (unlike a time limit) gives the same answer on any machine.
NODE_LIMIT = 500


def repack(  # type: ignore[no-untyped-def]
    state,
    perm,
    counts,
    route_cost,
    objective,
    tables,
    neighbours,
    pins,
    min_count,
    target,
    limit,
    groups,
    size,
    deadline=np.inf,
):
    """Up to ``groups`` re-packings of ``size`` neighbouring routes of the chromosome
    (``perm``, ``counts``, in place, ``route_cost`` kept as :func:`planner.cost.evaluate`
    gives it), each kept if the squeeze's figure (``target``, the tables' hour weights)
    falls and no route ends past ``limit``; none begun after ``deadline``
    (:func:`time.monotonic`). Returns the figure's fall (0: none)."""
    from scipy.optimize import Bounds, LinearConstraint, milp  # 0.2 s to load: only here

    weights = tables[8]
    gained = 0.0
    for _ in range(groups):
        if time.monotonic() > deadline:
            break
        routes = _routes(perm, counts)
        group = _group(state, perm, routes, neighbours, size)
        if group is None:
            continue
        fields = np.array(sorted(j for i in group for j in routes[i]), dtype=np.int64)
        cost, base = _linear_hours(group, routes, fields, route_cost, tables)
        g, f = cost.shape
        # Variables: x[a, k] (field k to the group's machine a) at a * f + k, then the
        # overloads o[a] at g * f + a.
        share = np.zeros((f, g * f + g))
        load = np.zeros((g, g * f + g))
        fields_of = np.zeros((g, g * f + g))
        upper = np.concatenate([np.ones(g * f), np.full(g, np.inf)])
        for a, i in enumerate(group):
            share[np.arange(f), a * f + np.arange(f)] = 1.0
            load[a, a * f : (a + 1) * f] = cost[a]
            fields_of[a, a * f : (a + 1) * f] = 1.0
            pinned = (pins[fields] >= 0) & (pins[fields] != i)
            upper[a * f : (a + 1) * f][pinned] = 0.0  # a pinned field stays on its machine
        overload = load.copy()
        overload[np.arange(g), g * f + np.arange(g)] = -1.0
        found = milp(
            np.concatenate([(weights[group][:, None] * cost).ravel(), np.full(g, OVERLOAD)]),
            constraints=[
                LinearConstraint(share, 1.0, 1.0),
                LinearConstraint(overload, -np.inf, target - base),
                LinearConstraint(load, -np.inf, limit - base),
                LinearConstraint(fields_of, min_count, np.inf),
            ],
            integrality=np.concatenate([np.ones(g * f), np.zeros(g)]),
            bounds=Bounds(0.0, upper),
            options={"node_limit": NODE_LIMIT},
        )
        if found.x is None:
            continue
        chosen = found.x[: g * f].reshape(g, f) > 0.5
        new = {
            i: _rebuild(i, routes[i], fields[chosen[a]], pins, tables) for a, i in enumerate(group)
        }
        if all(sorted(new[i]) == sorted(routes[i]) for i in group):
            continue
        routes = [new.get(i, r) for i, r in enumerate(routes)]
        new_perm = np.array([j for r in routes for j in r], dtype=perm.dtype)
        new_counts = np.array([len(r) for r in routes], dtype=counts.dtype)
        improve_routes(new_perm, new_counts, tables[0], tables[1], tables[2], neighbours, pins)
        new_cost = np.empty_like(route_cost)
        evaluate(new_perm, new_counts, objective, tables, new_cost)
        before = squeeze_figure(route_cost, target, weights)
        after = squeeze_figure(new_cost, target, weights)
        if after < before and new_cost.max() <= limit:
            perm[:], counts[:], route_cost[:] = new_perm, new_counts, new_cost
            gained += before - after
    return gained


def _routes(perm, counts):  # type: ignore[no-untyped-def]
    out, begin = [], 0
    for c in counts:
        out.append([int(j) for j in perm[begin : begin + int(c)]])
        begin += int(c)
    return out


def _group(state, perm, routes, neighbours, size):  # type: ignore[no-untyped-def]
    """The route of a random field and ``size - 1`` others, each drawn among the routes
    the group's fields' nearest neighbours lie on (more often where more of them lie);
    None if no other route is near."""
    where = np.empty(perm.shape[0], dtype=np.int64)
    for i, r in enumerate(routes):
        where[r] = i
    group = [int(where[perm[randint(state, perm.shape[0])]])]
    for _ in range(size - 1):
        near = where[neighbours[[j for i in group for j in routes[i]]].ravel()]
        near = near[~np.isin(near, group)]
        if near.size == 0:
            break
        group.append(int(near[randint(state, near.size)]))
    return group if len(group) > 1 else None


def _linear_hours(group, routes, fields, route_cost, tables):  # type: ignore[no-untyped-def]
    """[group's machine, field] the hours a field costs the machine's route in the linear
    model (see the module), and [group's machine] the route's hours that do not depend on
    its fields: its hours less what its own fields cost it."""
    dist, start_dist, end_dist, road_h, task_hours = (tables[k] for k in (0, 1, 2, 3, 5))
    column = {int(j): k for k, j in enumerate(fields)}
    cost = np.empty((len(group), len(fields)))
    base = np.empty(len(group))
    for a, i in enumerate(group):
        route = routes[i]
        road = _insertions_m(i, route, fields, dist, start_dist, end_dist).min(axis=1)
        own = [column[j] for j in route]
        if route:
            road[own] = _removals_m(i, route, dist, start_dist, end_dist)
        cost[a] = task_hours[i, fields] + road_h[i] * road
        base[a] = route_cost[i] - cost[a, own].sum()
    return cost, base


def _insertions_m(i, route, fields, dist, start_dist, end_dist):  # type: ignore[no-untyped-def]
    """[field, place] the road a field adds to machine i's ``route`` at each place (0:
    before its first field, len(route): after its last), metres."""
    fields = np.asarray(fields, dtype=np.int64)
    if not route:
        return (start_dist[i, fields] + end_dist[i, fields])[:, None]
    r = np.asarray(route)
    into = np.column_stack([start_dist[i, fields], dist[np.ix_(r, fields)].T])
    out = np.column_stack([dist[np.ix_(fields, r)], end_dist[i, fields]])
    old = np.concatenate([[start_dist[i, r[0]]], dist[r[:-1], r[1:]], [end_dist[i, r[-1]]]])
    return into + out - old[None, :]


def _removals_m(i, route, dist, start_dist, end_dist):  # type: ignore[no-untyped-def]
    """[place] the road leaving each field out of machine i's ``route`` saves, metres."""
    r = np.asarray(route)
    if len(r) == 1:
        return np.array([start_dist[i, r[0]] + end_dist[i, r[0]]])
    legs = np.concatenate([[start_dist[i, r[0]]], dist[r[:-1], r[1:]], [end_dist[i, r[-1]]]])
    bridge = np.empty(len(r))
    bridge[0] = start_dist[i, r[1]]
    bridge[-1] = end_dist[i, r[-2]]
    bridge[1:-1] = dist[r[:-2], r[2:]]
    return legs[:-1] + legs[1:] - bridge


def _rebuild(i, route, fields, pins, tables):  # type: ignore[no-untyped-def]
    """Machine i's route of ``fields``: those of ``route`` in their order, each other one
    at its cheapest place, the farthest from the machine's start first (never before a
    pinned first field)."""
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    mine = {int(j) for j in fields}
    new = [j for j in route if j in mine]
    for j in sorted(mine.difference(new), key=lambda j: (-start_dist[i, j], j)):
        added = _insertions_m(i, new, [j], dist, start_dist, end_dist)[0]
        if new and pins[new[0]] == i:
            added[0] = np.inf
        new.insert(int(np.argmin(added)), j)
    return new
