"""Population-level kernels shared by the genetic solvers: initial counts, tournament
selection (§4.2), population diversity (formula 19) and elitism."""

from __future__ import annotations

import numpy as np
from numba import njit

from planner.rng import randint, shuffle


@njit(cache=True, nogil=True)
def random_counts(state, n, m, min_count, counts):  # type: ignore[no-untyped-def]
    """A uniformly random composition of n tasks into m machines, each >= min_count."""
    free = n - m * min_count
    # Stars and bars: choose m-1 bar positions among free + m - 1 slots.
    slots = np.arange(free + m - 1)
    shuffle(state, slots)
    bars = np.sort(slots[: m - 1])
    prev = -1
    for i in range(m - 1):
        counts[i] = bars[i] - prev - 1 + min_count
        prev = bars[i]
    counts[m - 1] = free + m - 1 - prev - 1 + min_count


@njit(cache=True, nogil=True)
def tournament(state, costs, size, winners):  # type: ignore[no-untyped-def]
    """§4.2: fill ``winners`` with the index of the fittest (lowest cost, fitness 1/f of
    formula 7) of ``size`` individuals drawn at random, once per slot."""
    pop = costs.shape[0]
    for k in range(winners.shape[0]):
        best = randint(state, pop)
        for _ in range(size - 1):
            other = randint(state, pop)
            if costs[other] < costs[best]:
                best = other
        winners[k] = best


@njit(cache=True, nogil=True)
def positional_similarity(perms, div):  # type: ignore[no-untyped-def]
    """Formula (19) in linear time: ``div[p]`` = mean over the other individuals q of
    sim(p, q), the share of positions where p and q hold the same task.

    Summing sim(p, q) over q is, position by position, how many others hold p's task
    there; one count table per position gives it in O(N n) instead of O(N^2 n).
    """
    pop, n = perms.shape
    seen = np.zeros(n, dtype=np.int64)
    div[:] = 0.0
    for k in range(n):
        for p in range(pop):
            seen[perms[p, k]] += 1
        for p in range(pop):
            div[p] += seen[perms[p, k]] - 1
        for p in range(pop):
            seen[perms[p, k]] = 0
    if pop > 1:
        for p in range(pop):
            div[p] /= n * (pop - 1)


@njit(cache=True, nogil=True)
def keep_elite(
    perms, counts, costs, route_costs, elite_perm, elite_counts, elite_cost, elite_route
):  # type: ignore[no-untyped-def]
    """Put the best chromosome found so far back in place of the worst one if the
    population lost it."""
    best = np.argmin(costs)
    if costs[best] <= elite_cost:
        return
    worst = np.argmax(costs)
    perms[worst, :] = elite_perm
    counts[worst, :] = elite_counts
    costs[worst] = elite_cost
    route_costs[worst, :] = elite_route
