"""planner.relaxation: the duals of the assignment relaxation against its closed form on
uniform machines, with busy machines and pins; the bound they give; the squeeze's hour
weights, and that the squeeze's moves go by them."""

import dataclasses
import math

import numpy as np
import pytest
from helpers.chromosomes import NO_PINS, SETTINGS, chromosomes, least_over_insertions, problem_for
from hypothesis import given
from hypothesis import strategies as st

from planner import relaxation
from planner.cost import CostTables, Objective, evaluate, fleet_value
from planner.hybrid import HybridParams
from planner.local_search import allocation_search, nearest_neighbours
from planner.moves import recreate
from planner.relaxation import hour_weights, machine_weights, unavoidable_hours, weighted_bound
from planner.solve import solve, stop_after


def uniform(areas, speeds):
    """Machine i does task j in areas[j] / speeds[i] hours: the relaxation's optimum shares
    the work so that every machine ends at C = sum(areas) / sum(speeds), and its duals are
    the speeds, normalised."""
    return np.asarray(areas, float)[None, :] / np.asarray(speeds, float)[:, None]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_uniform_machines_weigh_as_their_speeds(seed):
    rng = np.random.default_rng(seed)
    areas, speeds = rng.uniform(1, 10, 40), rng.uniform(1, 8, 6)
    costs = uniform(areas, speeds)
    weights = machine_weights(costs)
    np.testing.assert_allclose(weights, speeds / speeds.sum(), rtol=1e-6)
    assert weighted_bound(costs, weights) == pytest.approx(areas.sum() / speeds.sum(), rel=1e-9)


def test_busy_machines_start_later_and_raise_the_bound():
    areas, speeds, ready = np.full(30, 2.0), np.array([1.0, 2.0, 4.0]), np.array([3.0, 0.0, 1.0])
    costs = uniform(areas, speeds)
    weights = machine_weights(costs, ready)
    # sum_i speeds_i (C - ready_i) = sum(areas) while every machine works: C = 67 / 7.
    expected = (areas.sum() + speeds @ ready) / speeds.sum()
    np.testing.assert_allclose(weights, speeds / speeds.sum(), rtol=1e-6)
    assert weighted_bound(costs, weights, ready) == pytest.approx(expected, rel=1e-9)


def test_a_pinned_task_stays_with_its_machine():
    # Task 0 takes 10 h on either machine and is pinned to machine 0; the two others, 1 h
    # each, go to machine 1: the makespan is 10 h, set by machine 0 alone.
    costs = np.array([[10.0, 1.0, 1.0], [10.0, 1.0, 1.0]])
    weights = machine_weights(costs, pinned=np.array([0, -1, -1]))
    np.testing.assert_allclose(weights, [1.0, 0.0], atol=1e-9)
    free = machine_weights(costs)  # unpinned: 12 h shared by two machines alike
    np.testing.assert_allclose(free, [0.5, 0.5], atol=1e-9)
    assert weighted_bound(costs, free) == pytest.approx(6.0)


def test_the_bound_is_below_every_assignment():
    rng = np.random.default_rng(7)
    costs = rng.uniform(1.0, 5.0, (3, 7))  # unrelated machines
    bound = weighted_bound(costs, machine_weights(costs))
    best = math.inf
    for code in range(3**7):
        machine = [(code // 3**j) % 3 for j in range(7)]
        loads = np.zeros(3)
        for j, i in enumerate(machine):
            loads[i] += costs[i, j]
        best = min(best, loads.max())
    assert bound <= best + 1e-9
    assert bound > 0.8 * best  # and not a trivial one


def test_bad_costs_are_refused_and_no_time_means_no_weights():
    with pytest.raises(ValueError, match="finite hours"):
        machine_weights(np.array([[1.0, np.inf]]))
    assert machine_weights(np.ones((2, 3)), time_limit=0.0) is None


def test_hour_weights_are_the_duals_times_the_machines_or_all_one():
    problem = problem_for(30, 4, 5, min_count=0)
    tables = CostTables.of(problem)
    weights = hour_weights(tables)
    assert weights.sum() == pytest.approx(4.0)
    np.testing.assert_allclose(weights, 4 * machine_weights(unavoidable_hours(tables)), rtol=1e-9)
    # A machine busy past the others' end does not take all the weight.
    busy = CostTables.of(problem.starting_at([None] * 4, ready_h=[0.0, 0.0, 0.0, 1e4]))
    np.testing.assert_allclose(hour_weights(busy), weights, rtol=1e-9)
    assert weights.max() > 1.1 * weights.min()  # the machines of problem_for differ
    assert hour_weights(tables, deadline=0.0).tolist() == [1.0] * 4  # out of time
    alike = dataclasses.replace(tables, task_hours=np.ones((4, relaxation.MAX_VARIABLES)))
    assert hour_weights(alike).tolist() == [1.0] * 4  # too large to solve


def test_unavoidable_hours_are_the_service_and_half_the_two_shortest_legs_at_road_speed():
    problem = problem_for(6, 2, 4, min_count=0).starting_at([(0.0, 0.0), (2500.0, 2500.0)])
    tables = CostTables.of(problem)
    hours = relaxation.unavoidable_hours(tables)
    for i in range(2):
        for j in range(6):
            legs = [problem.dist[j, k] for k in range(6) if k != j]
            legs += [problem.start_dist[i, j], problem.end_dist[i, j]]
            share = sum(sorted(legs)[:2]) / 2.0 * tables.road_hours_per_m[i]
            assert hours[i, j] == pytest.approx(tables.task_hours[i, j] + share, rel=1e-12)


def squeezed_tables(problem, rng):
    tables = CostTables.of(problem)
    weights = rng.uniform(0.2, 3.0, problem.num_machines)
    return dataclasses.replace(tables, hour_weights=weights).kernel_args()


@SETTINGS
@given(chromosomes(min_count=0), st.integers(0, 2**31))
def test_recreate_under_the_squeeze_puts_a_task_where_the_weighed_figure_is_least(case, seed):
    state, perm, counts = case
    n, m = perm.size, counts.size
    rng = np.random.default_rng(seed)
    problem = problem_for(n, m, seed % 1000, min_count=0)
    tables = squeezed_tables(problem, rng)
    route = np.empty(m)
    evaluate(perm, counts, int(Objective.MAKESPAN), tables, route)
    target = 0.9 * route.max()
    t = int(perm[rng.integers(n)])

    def figure(p, c):
        evaluate(p, c, int(Objective.MAKESPAN), tables, route)
        lengths = np.empty(m)
        evaluate(p, c, int(Objective.MINMAX), tables, lengths)
        return fleet_value(int(Objective.MAKESPAN), route, lengths, -target, tables[8])

    best = least_over_insertions(perm, counts, t, figure)
    recreate(
        state, perm, counts, int(Objective.MAKESPAN), tables, NO_PINS(n),
        np.array([t], dtype=np.int64), -target,
    )  # fmt: skip
    assert figure(perm, counts) == pytest.approx(best, rel=1e-9)


@SETTINGS
@given(chromosomes(min_count=0), st.integers(0, 2**31), st.integers(1, 15))
def test_the_local_search_under_the_squeeze_never_raises_the_weighed_figure(case, seed, moves):
    _, perm, counts = case
    n, m = perm.size, counts.size
    rng = np.random.default_rng(seed)
    problem = problem_for(n, m, seed % 1000, min_count=0)
    tables = squeezed_tables(problem, rng)
    route, lengths = np.empty(m), np.empty(m)
    evaluate(perm, counts, int(Objective.MAKESPAN), tables, route)
    target = 0.95 * route.max()

    def figure():
        evaluate(perm, counts, int(Objective.MAKESPAN), tables, route)
        evaluate(perm, counts, int(Objective.MINMAX), tables, lengths)
        return fleet_value(int(Objective.MAKESPAN), route, lengths, -target, tables[8])

    before = figure()
    allocation_search(
        perm, counts, int(Objective.MAKESPAN), tables, nearest_neighbours(problem.dist, 5), 0,
        20, NO_PINS(n), np.inf, np.zeros(n, dtype=np.bool_), False, moves, False, -target,
    )  # fmt: skip
    assert figure() <= before + 1e-9 * max(1.0, before)


def test_solve_weighs_the_hours_under_the_squeeze_the_same_way_for_the_same_seed():
    problem = problem_for(80, 8, 2)
    runs = [
        solve(
            problem, "makespan", "hybrid", stop_after(6), seed=3, params=HybridParams(weigh_hours=w)
        )
        for w in (True, True, False)
    ]
    assert runs[0].routes == runs[1].routes
    assert runs[0].routes != runs[2].routes  # the weights steer the search
