"""Genetic and local-search operators on the two-part chromosome (§4.1), as numba kernels.

Every operator keeps a chromosome valid: ``perm`` stays a permutation of the tasks and
``counts`` keeps its sum and its lower bound. Operators take the explicit random state
of :mod:`planner.rng` and write into caller-owned arrays.

Crossover (§4.3.1-4.3.2): OX and PMX on the first part; on the second part "a random
breakpoint is selected and the two gene segments are reversed in order", which we read
as swapping the two segments (a rotation), keeping the counts' sum.
Mutation (§4.4): swap and insert on both parts; ``shift_count`` (ours, not the paper's)
moves one task's worth of count between two machines, which the paper's operators never
do: with them alone a chromosome's multiset of counts is fixed at birth.
Local search (§4.5): the paper's 2-opt (reverse a random stretch of both parts, keep it
if better) and the circle modification (2-opt on every route to a local optimum).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from planner.pins import first_fixed
from planner.rng import randint

OX = 0
PMX = 1
SWAP = 0
INSERT = 1


@njit(cache=True, nogil=True)
def _segment(state, n):  # type: ignore[no-untyped-def]
    """A random stretch [a, b) with 0 <= a < b <= n."""
    a = randint(state, n)
    b = randint(state, n)
    if a > b:
        a, b = b, a
    return a, b + 1


@njit(cache=True, nogil=True)
def order_crossover(state, first, second, child):  # type: ignore[no-untyped-def]
    """OX: ``child`` keeps a random stretch of ``first`` in place; the other genes follow
    in the order they have in ``second``."""
    n = first.shape[0]
    a, b = _segment(state, n)
    used = np.zeros(n, dtype=np.bool_)
    for k in range(a, b):
        child[k] = first[k]
        used[first[k]] = True
    pos = 0
    for k in range(n):
        gene = second[k]
        if used[gene]:
            continue
        if pos == a:
            pos = b
        child[pos] = gene
        pos += 1


@njit(cache=True, nogil=True)
def partially_mapped_crossover(state, first, second, child):  # type: ignore[no-untyped-def]
    """PMX: ``child`` keeps a random stretch of ``first``; outside it, genes of ``second``
    are placed where they are, replaced through the stretch's mapping when taken."""
    n = first.shape[0]
    a, b = _segment(state, n)
    in_segment = np.zeros(n, dtype=np.bool_)
    where_first = np.empty(n, dtype=np.int64)
    for k in range(n):
        where_first[first[k]] = k
    for k in range(a, b):
        child[k] = first[k]
        in_segment[first[k]] = True
    for k in range(n):
        if a <= k < b:
            continue
        gene = second[k]
        while in_segment[gene]:
            gene = second[where_first[gene]]
        child[k] = gene


@njit(cache=True, nogil=True)
def rotate_counts(state, counts, child_counts):  # type: ignore[no-untyped-def]
    """Second part of a crossover: swap the segments before and after a random breakpoint."""
    m = counts.shape[0]
    cut = randint(state, m)
    for i in range(m):
        child_counts[i] = counts[(i + cut) % m]


@njit(cache=True, nogil=True)
def crossover(state, kind, first, second, first_counts, child, child_counts):  # type: ignore[no-untyped-def]
    """One child of ``first`` (with ``second`` as donor) by OX or PMX."""
    if kind == OX:
        order_crossover(state, first, second, child)
    else:
        partially_mapped_crossover(state, first, second, child)
    rotate_counts(state, first_counts, child_counts)


@njit(cache=True, nogil=True)
def _swap(arr, i, j):  # type: ignore[no-untyped-def]
    tmp = arr[i]
    arr[i] = arr[j]
    arr[j] = tmp


@njit(cache=True, nogil=True)
def _move(arr, src, dst):  # type: ignore[no-untyped-def]
    """Take arr[src] out and insert it so that it lands at index dst."""
    gene = arr[src]
    if src < dst:
        for k in range(src, dst):
            arr[k] = arr[k + 1]
    else:
        for k in range(src, dst, -1):
            arr[k] = arr[k - 1]
    arr[dst] = gene


@njit(cache=True, nogil=True)
def swap_mutation(state, perm, counts):  # type: ignore[no-untyped-def]
    """§4.4.1: exchange two tasks, and two machines' counts."""
    n, m = perm.shape[0], counts.shape[0]
    _swap(perm, randint(state, n), randint(state, n))
    if m > 1:
        _swap(counts, randint(state, m), randint(state, m))


@njit(cache=True, nogil=True)
def insert_mutation(state, perm, counts):  # type: ignore[no-untyped-def]
    """§4.4.2: move one task before another, and one count before another."""
    n, m = perm.shape[0], counts.shape[0]
    _move(perm, randint(state, n), randint(state, n))
    if m > 1:
        _move(counts, randint(state, m), randint(state, m))


@njit(cache=True, nogil=True)
def shift_count(state, counts, min_count):  # type: ignore[no-untyped-def]
    """Ours: move one unit of count from a machine that can spare it to another machine."""
    m = counts.shape[0]
    if m < 2:
        return
    src = randint(state, m)
    for _ in range(m):
        if counts[src] > min_count:
            break
        src = (src + 1) % m
    if counts[src] <= min_count:
        return
    dst = randint(state, m - 1)
    if dst >= src:
        dst += 1
    counts[src] -= 1
    counts[dst] += 1


@njit(cache=True, nogil=True)
def mutate(state, kind, perm, counts, min_count, with_shift):  # type: ignore[no-untyped-def]
    if kind == SWAP:
        swap_mutation(state, perm, counts)
    else:
        insert_mutation(state, perm, counts)
    if with_shift:
        shift_count(state, counts, min_count)


@njit(cache=True, nogil=True)
def reverse(arr, a, b):  # type: ignore[no-untyped-def]
    """Reverse arr[a..b] inclusive."""
    while a < b:
        _swap(arr, a, b)
        a += 1
        b -= 1


@njit(cache=True, nogil=True)
def random_two_opt(state, perm, counts):  # type: ignore[no-untyped-def]
    """§4.5(1): reverse a random stretch of the task order and of the counts."""
    n, m = perm.shape[0], counts.shape[0]
    a, b = _segment(state, n)
    reverse(perm, a, b - 1)
    if m > 1:
        a, b = _segment(state, m)
        reverse(counts, a, b - 1)


@njit(cache=True, nogil=True)
def leg(u, v, machine, dist, start_dist, end_dist):  # type: ignore[no-untyped-def]
    """Distance between route nodes; -1 is the machine's start, -2 its end.

    The three tables are read first and the answer picked among the numbers (a problem
    has a task and a machine, so the reads stay inside them): with a branch between the
    tables the kernels' every call paid numba's reference counting of the three arrays
    (~30 ns a call, 50 times the read: an insertion scan of 5 600 places took 0.49 ms,
    0.01 ms so; benchmarks/RESULTS.md, 2026-11-28)."""
    at_u = max(u, 0)
    at_v = max(v, 0)
    return _pick_leg(u, v, dist[at_u, at_v], start_dist[machine, at_v], end_dist[machine, at_u])


@njit(cache=True, nogil=True)
def _pick_leg(u, v, between, from_start, to_end):  # type: ignore[no-untyped-def]
    """:func:`leg`'s answer among the three distances read."""
    if u == -1:
        if v == -2:
            return 0.0
        return from_start
    if v == -2:
        return to_end
    return between


@njit(cache=True, nogil=True)
def circle_modification(perm, begin, count, machine, dist, start_dist, end_dist, fixed):  # type: ignore[no-untyped-def]
    """§4.5(2): improve one route's Hamilton circle (start, tasks, end) by 2-opt exchanges
    until none shortens it. Returns the total gain. Assumes ``dist`` is symmetric.
    The first ``fixed`` tasks (0 or 1: a pinned task) stay where they are."""
    if count < 2:
        return 0.0
    nodes = np.empty(count + 2, dtype=np.int64)
    nodes[0] = -1
    for k in range(count):
        nodes[k + 1] = perm[begin + k]
    nodes[count + 1] = -2
    gain = 0.0
    improved = True
    while improved:
        improved = False
        for i in range(fixed, count):
            a, b = nodes[i], nodes[i + 1]
            d_ab = leg(a, b, machine, dist, start_dist, end_dist)
            for j in range(i + 2, count + 1):
                c, d = nodes[j], nodes[j + 1]
                delta = (
                    leg(a, c, machine, dist, start_dist, end_dist)
                    + leg(b, d, machine, dist, start_dist, end_dist)
                    - d_ab
                    - leg(c, d, machine, dist, start_dist, end_dist)
                )
                if delta < -1e-10:
                    reverse(nodes, i + 1, j)
                    gain -= delta
                    improved = True
                    b = nodes[i + 1]
                    d_ab = leg(a, b, machine, dist, start_dist, end_dist)
    for k in range(count):
        perm[begin + k] = nodes[k + 1]
    return gain


@njit(cache=True, nogil=True)
def edge(u, v, machine, dist, start_dist, end_dist):  # type: ignore[no-untyped-def]
    """Length of an undirected edge between route nodes (-1 start, -2 end). (Read first,
    then picked, as :func:`leg` is, for its speed.)"""
    at_u = max(u, 0)
    at_v = max(v, 0)
    return _pick_edge(
        u, v, dist[at_u, at_v], start_dist[machine, at_v], start_dist[machine, at_u],
        end_dist[machine, at_v], end_dist[machine, at_u],
    )  # fmt: skip


@njit(cache=True, nogil=True)
def _pick_edge(u, v, between, start_v, start_u, end_v, end_u):  # type: ignore[no-untyped-def]
    """:func:`edge`'s answer among the distances read."""
    if u < 0 and v < 0:
        return 0.0
    if u == -1:
        return start_v
    if v == -1:
        return start_u
    if u == -2:
        return end_v
    if v == -2:
        return end_u
    return between


@njit(cache=True, nogil=True)
def two_opt_neighbours(  # type: ignore[no-untyped-def]
    perm, begin, count, machine, dist, start_dist, end_dist, neighbours, where, fixed
):
    """2-opt on one route with candidate edges from each task's nearest neighbours:
    O(count k) per pass instead of the circle modification's O(count^2), for long routes.
    ``where`` is scratch of one int per task, all -1 on entry and on exit. The first
    ``fixed`` tasks (0 or 1: a pinned task) stay where they are."""
    if count < 2:
        return 0.0
    nodes = np.empty(count + 2, dtype=np.int64)
    nodes[0] = -1
    for k in range(count):
        t = perm[begin + k]
        nodes[k + 1] = t
        where[t] = k + 1
    nodes[count + 1] = -2
    gain = 0.0
    improved = True
    while improved:
        improved = False
        for i in range(1, count + 1):
            for direction in range(2):
                a = nodes[i]
                step = 1 if direction == 0 else -1
                b = nodes[i + step]
                d_ab = edge(a, b, machine, dist, start_dist, end_dist)
                for q in range(neighbours.shape[1]):
                    c = neighbours[a, q]
                    d_ac = dist[a, c]
                    if d_ac >= d_ab:
                        break
                    j = where[c]
                    if j < 0 or j == i + step or j == i:
                        continue
                    d = nodes[j + step]
                    delta = (
                        d_ac
                        + edge(b, d, machine, dist, start_dist, end_dist)
                        - d_ab
                        - edge(c, d, machine, dist, start_dist, end_dist)
                    )
                    if delta < -1e-10:
                        if direction == 0:
                            lo, hi = (i + 1, j) if j > i else (j + 1, i)
                        else:
                            lo, hi = (i, j - 1) if j > i else (j, i - 1)
                        if lo <= fixed:
                            continue
                        reverse(nodes, lo, hi)
                        for k in range(lo, hi + 1):
                            where[nodes[k]] = k
                        gain -= delta
                        improved = True
                        a = nodes[i]
                        b = nodes[i + step]
                        d_ab = edge(a, b, machine, dist, start_dist, end_dist)
    for k in range(count):
        perm[begin + k] = nodes[k + 1]
        where[nodes[k + 1]] = -1
    return gain


@njit(cache=True, nogil=True)
def improve_routes(perm, counts, dist, start_dist, end_dist, neighbours, pins):  # type: ignore[no-untyped-def]
    """Improve every route of a chromosome: the paper's circle modification when
    ``neighbours`` has no columns, the neighbour-list 2-opt otherwise; a pinned task
    (``pins``, see :mod:`planner.pins`) first in its route stays first."""
    begin = 0
    where = np.full(perm.shape[0], -1, dtype=np.int64)
    for i in range(counts.shape[0]):
        fixed = first_fixed(perm, begin, counts[i], i, pins)
        if neighbours.shape[1] == 0:
            circle_modification(perm, begin, counts[i], i, dist, start_dist, end_dist, fixed)
        else:
            two_opt_neighbours(
                perm, begin, counts[i], i, dist, start_dist, end_dist, neighbours, where, fixed
            )
        begin += counts[i]
