"""IGHOA, the improved genetic hybrid optimisation algorithm of the paper (§3-§4).

One generation (§4.6, steps 3-5) is one compiled call, :func:`generation`:
tournament selection (§4.2) → adaptive crossover (§4.3, formulas 8-18) → adaptive
mutation (§4.4, formulas 19-20) → elitism. The Python driver in :mod:`planner.solve`
then polishes the best chromosome with the paper's 2-opt and circle modification (§4.5,
:func:`polish`). Every reading of an ambiguous formula is written in docs/ighoa.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from planner.cost import evaluate
from planner.operators import (
    INSERT,
    OX,
    PMX,
    SWAP,
    crossover,
    improve_routes,
    mutate,
    random_two_opt,
)
from planner.pins import repair_pins
from planner.population import keep_elite, positional_similarity, tournament
from planner.rng import randint, shuffle, uniform


@dataclass(frozen=True)
class IGHOAParams:
    """The settings of §5.1 as defaults, plus the few the paper leaves open."""

    population: int = 200  # N
    pc_min: float = 0.4
    pc_mid: float = 0.55  # used when a chromosome's routes all cost the same
    pc_max: float = 0.85
    pm: float = 0.1  # initial mutation probability p_m
    tol_min: float = 0.05
    tol_max: float = 0.8
    tournament_size: int = 2  # not given by the paper
    two_opt_tries: int = 50  # random 2-opt attempts on the best per generation (§4.5(1))
    # The paper's algorithm by default, as `--algorithm ighoa` promises; beyond it (ours,
    # hybrid's defaults): mutation may move a task between machines' counts
    # (``shift_counts``), and ``local_search = "extended"`` adds relocate/exchange moves
    # between routes (planner.local_search) on the best and ``memetic`` others; "paper"
    # polishes the best with §4.5 only.
    shift_counts: bool = False
    local_search: str = "paper"
    memetic: int = 0
    neighbours: int = 10

    def __post_init__(self) -> None:
        if self.population < 2 or self.population % 2:
            raise ValueError(f"population must be an even number >= 2, not {self.population}")
        if not 0.0 <= self.pc_min <= self.pc_mid <= self.pc_max <= 1.0:
            raise ValueError("need 0 <= pc_min <= pc_mid <= pc_max <= 1")
        if not 0.0 <= self.pm <= 1.0:
            raise ValueError(f"pm must be a probability, not {self.pm}")
        if not 0.0 <= self.tol_min <= self.tol_max:
            raise ValueError("need 0 <= tol_min <= tol_max")
        if self.tournament_size < 1:
            raise ValueError("tournament_size must be at least 1")
        if self.two_opt_tries < 0:
            raise ValueError("two_opt_tries must not be negative")
        if self.local_search not in ("paper", "extended"):
            raise ValueError(f"local_search is 'paper' or 'extended', not {self.local_search!r}")
        if self.memetic < 0 or self.neighbours < 1:
            raise ValueError("memetic must be >= 0 and neighbours >= 1")


def adaptive_tolerance(
    progress: float, population: int, max_generations: int, tol_min: float, tol_max: float
) -> float:
    """Formulas (9), (10), (14): the tolerance sp from the share of the run done.

    ``progress`` stands for gen / MAXGEN, so that a wall-clock limit drives it the same way.
    """
    log_n = math.log(population)
    r = 2.0 * log_n * progress - log_n  # (9)
    big_r = 1.0 / (1.0 + math.exp(-r)) * (1.0 - progress + 1.0 / max_generations)  # (10)
    return tol_min + big_r * progress * (tol_max - tol_min)  # (14)


@njit(cache=True, nogil=True)
def crossover_probability(route_cost, pc_min, pc_mid, pc_max):  # type: ignore[no-untyped-def]
    """Formula (15)/(16), read as an interpolation between Pcmin and Pcmax by where the
    mean route cost lies between the cheapest and dearest route of the chromosome."""
    hi = route_cost.max()
    lo = route_cost.min()
    mean = route_cost.mean()
    if hi - lo <= 1e-12 * max(1.0, abs(hi)):
        return pc_mid
    return (pc_max * (hi - mean) + pc_min * (mean - lo)) / (hi - lo)


@njit(cache=True, nogil=True)
def overshoot(route_cost):  # type: ignore[no-untyped-def]
    """Formula (11): how far the dearest route exceeds the mean route."""
    mean = route_cost.mean()
    if mean <= 0.0:
        return 0.0
    return (route_cost.max() - mean) / mean


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
    sp,
    pc_min,
    pc_mid,
    pc_max,
    pm,
    tournament_size,
    shift_counts,
    elite_perm,
    elite_counts,
    elite_route,
    elite_cost,
):
    """One IGHOA generation in place on the population arrays; returns the number of
    crossovers and mutations done (for statistics). Children and mutants are repaired to
    keep their pinned tasks (:mod:`planner.pins`)."""
    pop, n = perms.shape

    # §4.2 tournament selection into a new population.
    winners = np.empty(pop, dtype=np.int64)
    tournament(state, costs, tournament_size, winners)
    sel_perms = perms[winners].copy()
    sel_counts = counts[winners].copy()
    sel_route = route_costs[winners].copy()
    sel_costs = costs[winners].copy()

    # §4.3 adaptive crossover on random pairs drawn without replacement.
    order = np.arange(pop)
    shuffle(state, order)
    crossovers = 0
    for k in range(0, pop - 1, 2):
        d, mo = order[k], order[k + 1]
        pc1 = crossover_probability(sel_route[d], pc_min, pc_mid, pc_max)
        pc2 = crossover_probability(sel_route[mo], pc_min, pc_mid, pc_max)
        f1, f2 = 1.0 / max(sel_costs[d], 1e-300), 1.0 / max(sel_costs[mo], 1e-300)
        w1 = f1 / (f1 + f2)  # (17)-(18): weights by fitness, summing to one
        pc = pc1 * w1 + pc2 * (1.0 - w1)
        if uniform(state) < pc:
            crossovers += 1
            kind1 = OX if overshoot(sel_route[d]) < sp else PMX
            kind2 = OX if overshoot(sel_route[mo]) < sp else PMX
            crossover(state, kind1, sel_perms[d], sel_perms[mo], sel_counts[d], perms[k], counts[k])
            crossover(
                state,
                kind2,
                sel_perms[mo],
                sel_perms[d],
                sel_counts[mo],
                perms[k + 1],
                counts[k + 1],
            )
        else:
            perms[k] = sel_perms[d]
            counts[k] = sel_counts[d]
            perms[k + 1] = sel_perms[mo]
            counts[k + 1] = sel_counts[mo]
    for p in range(pop):
        repair_pins(perms[p], counts[p], pins, min_count)
        costs[p] = evaluate(perms[p], counts[p], objective, tables, route_costs[p])

    # §4.4 adaptive mutation: formula (19) diversity and (20) rate per individual.
    div = np.empty(pop)
    positional_similarity(perms, div)
    fit_hi = 1.0 / max(costs.min(), 1e-300)
    fit_lo = 1.0 / max(costs.max(), 1e-300)
    mutations = 0
    for p in range(pop):
        fitness = 1.0 / max(costs[p], 1e-300)
        fit = 1.0 if fit_hi - fit_lo <= 0.0 else (fitness - fit_lo) / (fit_hi - fit_lo)
        rate = (1.0 - fit) * pm + div[p] * fit  # (20)
        if uniform(state) < rate:
            mutations += 1
            kind = SWAP if randint(state, 2) == 0 else INSERT
            mutate(state, kind, perms[p], counts[p], min_count, shift_counts)
            repair_pins(perms[p], counts[p], pins, min_count)
            costs[p] = evaluate(perms[p], counts[p], objective, tables, route_costs[p])
    keep_elite(perms, counts, costs, route_costs, elite_perm, elite_counts, elite_cost, elite_route)
    return crossovers, mutations


@njit(cache=True, nogil=True)
def polish(  # type: ignore[no-untyped-def]
    state, perm, counts, objective, tables, tries, route_cost, neighbours, pins, min_count
):
    """§4.5 on one chromosome in place: ``tries`` random 2-opt reversals of both parts
    (each repaired for its pins), each kept only if it lowers the cost, then the circle
    modification of every route (neighbour-list 2-opt when ``neighbours`` has columns).
    Returns the new cost."""
    dist, start_dist, end_dist = tables[0], tables[1], tables[2]
    cost = evaluate(perm, counts, objective, tables, route_cost)
    trial_perm = perm.copy()
    trial_counts = counts.copy()
    trial_route = route_cost.copy()
    for _ in range(tries):
        trial_perm[:] = perm
        trial_counts[:] = counts
        random_two_opt(state, trial_perm, trial_counts)
        repair_pins(trial_perm, trial_counts, pins, min_count)
        trial = evaluate(trial_perm, trial_counts, objective, tables, trial_route)
        if trial < cost - 1e-12:
            perm[:] = trial_perm
            counts[:] = trial_counts
            route_cost[:] = trial_route
            cost = trial
    improve_routes(perm, counts, dist, start_dist, end_dist, neighbours, pins)
    return evaluate(perm, counts, objective, tables, route_cost)
