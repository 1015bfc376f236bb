"""§3.2.1 path pre-planning by simulated annealing.

One giant tour through every task, from the garage and back (machine 0's start and end),
perturbed by segment reversals and accepted by the Metropolis criterion, with geometric
cooling from ``t_start`` down to ``t_end`` and a Markov chain of ``chain`` moves per
temperature. The paper gives no cooling factor; ``alpha`` is ours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from planner.operators import leg, reverse
from planner.rng import randint, uniform


@dataclass(frozen=True)
class AnnealingParams:
    t_start: float = 120.0
    t_end: float = 1.0
    chain: int = 100
    alpha: float = 0.97

    def __post_init__(self) -> None:
        if not (self.t_start >= self.t_end > 0):
            raise ValueError(f"need t_start >= t_end > 0, got {self.t_start}, {self.t_end}")
        if self.chain < 1:
            raise ValueError(f"Markov chain length must be at least 1, not {self.chain}")
        if not 0.0 < self.alpha < 1.0:
            raise ValueError(f"cooling factor alpha must be in (0, 1), not {self.alpha}")


@njit(cache=True, nogil=True)
def anneal(state, perm, dist, start_dist, end_dist, t_start, t_end, alpha, chain):  # type: ignore[no-untyped-def]
    """Anneal the giant tour ``perm`` in place (it ends as the best tour seen); returns
    its length."""
    n = perm.shape[0]
    nodes = np.empty(n + 2, dtype=np.int64)
    nodes[0] = -1
    for k in range(n):
        nodes[k + 1] = perm[k]
    nodes[n + 1] = -2
    current = 0.0
    for k in range(n + 1):
        current += leg(nodes[k], nodes[k + 1], 0, dist, start_dist, end_dist)
    best = current
    best_nodes = nodes.copy()
    t = t_start
    while t >= t_end and n >= 2:
        for _ in range(chain):
            # Two edges (i, i+1) and (j, j+1) of the closed tour, reverse what lies between.
            i = randint(state, n + 1)
            j = randint(state, n + 1)
            if i > j:
                i, j = j, i
            if j - i < 2:
                continue
            a, b, c, d = nodes[i], nodes[i + 1], nodes[j], nodes[j + 1]
            delta = (
                leg(a, c, 0, dist, start_dist, end_dist)
                + leg(b, d, 0, dist, start_dist, end_dist)
                - leg(a, b, 0, dist, start_dist, end_dist)
                - leg(c, d, 0, dist, start_dist, end_dist)
            )
            if delta < 0.0 or uniform(state) < math.exp(-delta / t):
                reverse(nodes, i + 1, j)
                current += delta
                if current < best - 1e-9:
                    best = current
                    best_nodes[:] = nodes
        t *= alpha
    for k in range(n):
        perm[k] = best_nodes[k + 1]
    return best
