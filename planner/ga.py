"""The classic genetic algorithm, the paper's "GA" baseline: the same two-part chromosome,
random initial population (no SA pre-planning), tournament selection, OX crossover and
swap/insert mutation at fixed rates, elitism, and no local search."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from planner.cost import evaluate
from planner.operators import INSERT, OX, SWAP, crossover, mutate
from planner.pins import repair_pins
from planner.population import keep_elite, tournament
from planner.rng import randint, shuffle, uniform


@dataclass(frozen=True)
class GAParams:
    population: int = 200
    crossover_rate: float = 0.85
    mutation_rate: float = 0.1
    tournament_size: int = 2

    def __post_init__(self) -> None:
        if self.population < 2 or self.population % 2:
            raise ValueError(f"population must be an even number >= 2, not {self.population}")
        for name in ("crossover_rate", "mutation_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be a probability, not {getattr(self, name)}")
        if self.tournament_size < 1:
            raise ValueError("tournament_size must be at least 1")


@njit(cache=True, nogil=True)
def generation(  # type: ignore[no-untyped-def]
    state,
    perms,
    counts,
    costs,
    route_costs,
    objective,
    tables,
    min_count,
    pins,
    crossover_rate,
    mutation_rate,
    tournament_size,
    elite_perm,
    elite_counts,
    elite_route,
    elite_cost,
):
    """One classic GA generation in place; every chromosome keeps its pinned tasks."""
    pop = perms.shape[0]
    winners = np.empty(pop, dtype=np.int64)
    tournament(state, costs, tournament_size, winners)
    sel_perms = perms[winners].copy()
    sel_counts = counts[winners].copy()
    order = np.arange(pop)
    shuffle(state, order)
    for k in range(0, pop - 1, 2):
        d, mo = order[k], order[k + 1]
        if uniform(state) < crossover_rate:
            crossover(state, OX, sel_perms[d], sel_perms[mo], sel_counts[d], perms[k], counts[k])
            crossover(
                state, OX, sel_perms[mo], sel_perms[d], sel_counts[mo], perms[k + 1], counts[k + 1]
            )
        else:
            perms[k] = sel_perms[d]
            counts[k] = sel_counts[d]
            perms[k + 1] = sel_perms[mo]
            counts[k + 1] = sel_counts[mo]
    for p in range(pop):
        if uniform(state) < mutation_rate:
            kind = SWAP if randint(state, 2) == 0 else INSERT
            mutate(state, kind, perms[p], counts[p], min_count, False)
        repair_pins(perms[p], counts[p], pins, min_count)
        costs[p] = evaluate(perms[p], counts[p], objective, tables, route_costs[p])
    keep_elite(perms, counts, costs, route_costs, elite_perm, elite_counts, elite_cost, elite_route)
