"""Every operator keeps the chromosome valid; local search reports true costs."""

import dataclasses

import numpy as np
import pytest
from helpers.chromosomes import NO_PINS, SETTINGS, assert_valid, chromosomes, problem_for
from hypothesis import given
from hypothesis import strategies as st

from planner import operators as ops
from planner.cost import CostTables, Objective, evaluate
from planner.ighoa import polish
from planner.local_search import improve_allocation, nearest_neighbours
from planner.population import positional_similarity


@SETTINGS
@given(chromosomes(), st.sampled_from(["ox", "pmx"]))
def test_crossovers_keep_a_permutation(case, kind):
    state, perm, counts = case
    n, m = perm.size, counts.size
    other = np.random.default_rng(int(perm.sum())).permutation(n).astype(np.int64)
    child = np.full(n, -1, dtype=np.int64)
    child_counts = np.zeros(m, dtype=np.int64)
    ops.crossover(
        state, ops.OX if kind == "ox" else ops.PMX, perm, other, counts, child, child_counts
    )
    assert_valid(child, child_counts, n, m)
    assert sorted(child_counts.tolist()) == sorted(counts.tolist())


@SETTINGS
@given(chromosomes(), st.sampled_from([ops.SWAP, ops.INSERT]), st.booleans())
def test_mutations_keep_validity(case, kind, shift):
    state, perm, counts = case
    n, m = perm.size, counts.size
    for _ in range(5):
        ops.mutate(state, kind, perm, counts, 1, shift)
        assert_valid(perm, counts, n, m)


@SETTINGS
@given(chromosomes(min_count=0))
def test_operators_respect_zero_minimum(case):
    state, perm, counts = case
    assert_valid(perm, counts, perm.size, counts.size, min_count=0)
    for _ in range(10):
        ops.shift_count(state, counts, 0)
        assert counts.min() >= 0 and counts.sum() == perm.size


@SETTINGS
@given(chromosomes())
def test_random_two_opt_keeps_validity(case):
    state, perm, counts = case
    ops.random_two_opt(state, perm, counts)
    assert_valid(perm, counts, perm.size, counts.size)


@SETTINGS
@given(chromosomes(), st.sampled_from(list(Objective)))
def test_local_search_keeps_validity_and_reports_true_cost(case, objective):
    state, perm, counts = case
    n, m = perm.size, counts.size
    problem = problem_for(n, m, int(perm[0]) + 7 * n)
    tables = CostTables.of(problem).kernel_args()
    route = np.empty(m)
    before = evaluate(perm, counts, int(objective), tables, route)
    nn = nearest_neighbours(problem.dist, 5)
    cost = polish(state, perm, counts, int(objective), tables, 20, route, nn[:, :0], NO_PINS(n), 1)
    assert_valid(perm, counts, n, m)
    check = np.empty(m)
    assert cost == pytest.approx(evaluate(perm, counts, int(objective), tables, check), rel=1e-12)
    assert cost <= before + 1e-9 * max(1.0, before)
    np.testing.assert_allclose(route, check)
    improve_allocation(perm, counts, int(objective), tables, nn, 1, 20, NO_PINS(n))
    assert_valid(perm, counts, n, m)
    after = evaluate(perm, counts, int(objective), tables, check)
    assert after <= cost + 1e-9 * max(1.0, cost)


@SETTINGS
@given(chromosomes(), st.booleans())
def test_route_improvement_never_lengthens_a_route(case, with_neighbours):
    _, perm, counts = case
    problem = problem_for(perm.size, counts.size, 3)
    tables = CostTables.of(problem)
    route = np.empty(counts.size)
    before = evaluate(perm, counts, 0, tables.kernel_args(), route)
    nn = nearest_neighbours(tables.dist, 4)[:, : 4 if with_neighbours else 0]
    ops.improve_routes(
        perm, counts, tables.dist, tables.start_dist, tables.end_dist, nn, NO_PINS(perm.size)
    )
    after = evaluate(perm, counts, 0, tables.kernel_args(), route)
    assert after <= before + 1e-9
    assert sorted(perm.tolist()) == list(range(perm.size))


def test_similarity_matches_quadratic_definition():
    rng = np.random.default_rng(5)
    perms = np.array([rng.permutation(12) for _ in range(9)], dtype=np.int64)
    perms[3] = perms[1]
    div = np.empty(9)
    positional_similarity(perms, div)
    sim = (perms[:, None, :] == perms[None, :, :]).mean(axis=2)
    expected = (sim.sum(axis=1) - 1.0) / (9 - 1)  # formula (19), self excluded
    np.testing.assert_allclose(div, expected)


@SETTINGS
@given(chromosomes(min_count=1), st.sampled_from(list(Objective)))
def test_optimal_split_is_optimal_for_its_order(case, objective):
    import itertools

    from planner.local_search import optimal_split

    _, perm, counts = case
    n, m = perm.size, counts.size
    if n > 12:
        perm, counts = perm[perm < 12], counts  # keep brute force small
        n = perm.size
        if n < m:
            return
        counts = np.ones(m, dtype=np.int64)
        counts[0] += n - m
    problem = problem_for(n, m, 11)
    tables = CostTables.of(problem).kernel_args()
    route = np.empty(m)
    best = np.inf
    for cuts in itertools.combinations(range(1, n), m - 1):
        trial = np.diff(np.array((0, *cuts, n))).astype(np.int64)
        best = min(best, evaluate(perm, trial, int(objective), tables, route))
    split = counts.copy()
    optimal_split(perm, split, int(objective), tables, 1, NO_PINS(n))
    assert_valid(perm, split, n, m)
    value = evaluate(perm, split, int(objective), tables, route)
    assert value <= best + 1e-6 * max(1.0, best)


def replanned_problem_for(n, m, seed):
    """``problem_for`` with machines at random points now, busy for random hours."""
    rng = np.random.default_rng(seed + 1)
    problem = problem_for(n, m, seed)
    starts = [(float(x), float(y)) for x, y in rng.uniform(0, 3000, size=(m, 2))]
    ready = rng.uniform(0, 3, size=m) * (rng.random(m) < 0.7)
    problem = dataclasses.replace(problem, min_tasks_per_machine=0)
    return problem.starting_at(starts, ready_h=ready.tolist())


@SETTINGS
@given(chromosomes(min_count=0), st.sampled_from(list(Objective)))
def test_local_search_with_starts_and_ready_times_never_worsens(case, objective):
    state, perm, counts = case
    n, m = perm.size, counts.size
    problem = replanned_problem_for(n, m, int(perm[0]) + 5 * n)
    tables = CostTables.of(problem).kernel_args()
    route = np.empty(m)
    before = evaluate(perm, counts, int(objective), tables, route)
    nn = nearest_neighbours(problem.dist, 5)
    cost = polish(state, perm, counts, int(objective), tables, 20, route, nn, NO_PINS(n), 0)
    assert cost <= before + 1e-9 * max(1.0, before)
    improve_allocation(perm, counts, int(objective), tables, nn, 0, 20, NO_PINS(n))
    assert_valid(perm, counts, n, m, min_count=0)
    after = evaluate(perm, counts, int(objective), tables, route)
    assert after <= cost + 1e-9 * max(1.0, cost)


@SETTINGS
@given(chromosomes(min_count=0), st.sampled_from(list(Objective)))
def test_optimal_split_with_ready_times_is_optimal_for_its_order(case, objective):
    import itertools

    from planner.local_search import optimal_split

    _, perm, counts = case
    perm = perm[perm < 9]
    n, m = perm.size, min(counts.size, 4)
    problem = replanned_problem_for(n, m, 13)
    tables = CostTables.of(problem).kernel_args()
    route = np.empty(m)
    best = np.inf
    # Every composition of n into m parts, empty routes allowed.
    for cuts in itertools.combinations_with_replacement(range(n + 1), m - 1):
        trial = np.diff(np.array((0, *cuts, n))).astype(np.int64)
        best = min(best, evaluate(perm, trial, int(objective), tables, route))
    split = np.zeros(m, dtype=np.int64)
    split[0] = n
    value = optimal_split(perm, split, int(objective), tables, 0, NO_PINS(n))
    assert_valid(perm, split, n, m, min_count=0)
    got = evaluate(perm, split, int(objective), tables, route)
    assert got <= best + 1e-6 * max(1.0, best)
    if objective in (Objective.DISTANCE, Objective.TIME, Objective.FUEL):
        assert value == pytest.approx(got, rel=1e-9)


def test_a_leg_and_an_edge_between_every_kind_of_node():
    """leg (directed: -1 the machine's start, -2 its end) and edge (undirected) read the
    right table for every pair of a task, the start and the end, and nothing for a route
    with no task (start to end)."""
    rng = np.random.default_rng(3)
    dist = rng.uniform(1.0, 9.0, (3, 3))
    start_dist, end_dist = rng.uniform(10.0, 19.0, (2, 3)), rng.uniform(20.0, 29.0, (2, 3))
    for machine in (0, 1):
        for u in (0, 1, 2):
            for v in (0, 1, 2):
                assert ops.leg(u, v, machine, dist, start_dist, end_dist) == dist[u, v]
                assert ops.edge(u, v, machine, dist, start_dist, end_dist) == dist[u, v]
            start, end = start_dist[machine, u], end_dist[machine, u]
            assert ops.leg(-1, u, machine, dist, start_dist, end_dist) == start
            assert ops.leg(u, -2, machine, dist, start_dist, end_dist) == end
            assert ops.edge(-1, u, machine, dist, start_dist, end_dist) == start
            assert ops.edge(u, -1, machine, dist, start_dist, end_dist) == start
            assert ops.edge(-2, u, machine, dist, start_dist, end_dist) == end
            assert ops.edge(u, -2, machine, dist, start_dist, end_dist) == end
        assert ops.leg(-1, -2, machine, dist, start_dist, end_dist) == 0.0
        assert ops.edge(-1, -2, machine, dist, start_dist, end_dist) == 0.0
        assert ops.edge(-2, -1, machine, dist, start_dist, end_dist) == 0.0
