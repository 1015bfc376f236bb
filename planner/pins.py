"""Pinned tasks: a field in progress kept with the machine working it, first in its route.

``pins[j]`` is the machine task j is pinned to, or -1 (:data:`planner.problem.NOT_PINNED`);
a machine has at most one pinned task. The genetic operators (crossover, mutation, the
random 2-opt) know nothing of pins: :func:`repair_pins` puts every chromosome they make
back in order, moving each pinned task to the front of its machine's route. The route
improvements (circle modification, neighbour 2-opt), the moves between routes and the
optimal split honour pins themselves, so they never undo a good solution by repair.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def pins_hold(perm, counts, pins):  # type: ignore[no-untyped-def]
    """Whether every pinned task is the first of its machine's route."""
    m = counts.shape[0]
    begin = 0
    first = np.full(m, -1, dtype=np.int64)
    for i in range(m):
        if counts[i] > 0:
            first[i] = perm[begin]
        begin += counts[i]
    for j in range(pins.shape[0]):
        i = pins[j]
        if i >= 0 and first[i] != j:
            return False
    return True


@njit(cache=True, nogil=True)
def repair_pins(perm, counts, pins, min_count):  # type: ignore[no-untyped-def]
    """Move every pinned task to the front of its machine's route (the others keep their
    order), then give a route short of ``min_count`` the last task of the longest route.
    In place; returns whether anything changed."""
    if pins_hold(perm, counts, pins):
        return False
    m = counts.shape[0]
    n = perm.shape[0]
    routes = np.empty((m, n), dtype=np.int64)
    sizes = np.zeros(m, dtype=np.int64)
    pinned_of = np.full(m, -1, dtype=np.int64)
    for j in range(n):
        if pins[j] >= 0:
            pinned_of[pins[j]] = j
    for i in range(m):
        if pinned_of[i] >= 0:
            routes[i, 0] = pinned_of[i]
            sizes[i] = 1
    begin = 0
    for i in range(m):
        for k in range(begin, begin + counts[i]):
            t = perm[k]
            if pins[t] < 0:
                routes[i, sizes[i]] = t
                sizes[i] += 1
        begin += counts[i]
    for i in range(m):
        while sizes[i] < min_count:
            donor = np.argmax(sizes)
            sizes[donor] -= 1
            routes[i, sizes[i]] = routes[donor, sizes[donor]]
            sizes[i] += 1
    begin = 0
    for i in range(m):
        for k in range(sizes[i]):
            perm[begin + k] = routes[i, k]
        counts[i] = sizes[i]
        begin += sizes[i]
    return True


@njit(cache=True, nogil=True)
def first_fixed(perm, begin, count, machine, pins):  # type: ignore[no-untyped-def]
    """1 when the route's first task is pinned to it (it must stay first), else 0."""
    if count > 0 and pins[perm[begin]] == machine:
        return 1
    return 0
