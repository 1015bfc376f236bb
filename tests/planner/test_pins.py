"""Pinned tasks (a field in progress kept with its machine, first in its route): every
operator, the local search, the split and the solver keep them; costs stay true."""

import dataclasses
import itertools

import numpy as np
import pytest
from helpers.chromosomes import problem_for
from hypothesis import given, settings
from hypothesis import strategies as st

from planner import operators as ops
from planner.cost import CostTables, Objective, evaluate, figures, split_routes
from planner.errors import ProblemError
from planner.ga import GAParams
from planner.ighoa import IGHOAParams, polish
from planner.local_search import improve_allocation, nearest_neighbours, optimal_split
from planner.pins import pins_hold, repair_pins
from planner.population import random_counts
from planner.rng import make_state
from planner.solve import MaxGenerations, solve, stop_after

SETTINGS = settings(max_examples=80, deadline=None, derandomize=True)


def pinned_problem(n, m, seed, min_count=1):
    """Random tasks; machines at random points now, busy for random hours; up to m tasks
    pinned, each to its own machine."""
    rng = np.random.default_rng(seed)
    problem = problem_for(n, m, seed, min_count, rng)
    starts = [(float(x), float(y)) for x, y in rng.uniform(0, 3000, size=(m, 2))]
    problem = problem.starting_at(starts, ready_h=rng.uniform(0, 2, size=m).tolist())
    k = int(rng.integers(1, min(n, m) + 1))
    pinned_tasks = rng.choice(n, size=k, replace=False)
    pinned_machines = rng.choice(m, size=k, replace=False)
    return problem.pinned(
        {int(j): int(i) for j, i in zip(pinned_tasks, pinned_machines, strict=True)}
    )


@st.composite
def pinned_cases(draw, min_count=1):
    n = draw(st.integers(2, 14))
    m = draw(st.integers(1, min(n, 5)))
    seed = draw(st.integers(0, 2**31))
    problem = pinned_problem(n, m, seed, min_count)
    state = make_state(seed)
    perm = np.random.default_rng(seed).permutation(n).astype(np.int64)
    counts = np.empty(m, dtype=np.int64)
    random_counts(state, n, m, min_count, counts)
    return state, problem, perm, counts


def pins_of(problem):
    return np.ascontiguousarray(problem.pinned_machine)


def assert_valid_and_pinned(problem, perm, counts, min_count):
    n, m = problem.num_tasks, problem.num_machines
    assert sorted(perm.tolist()) == list(range(n))
    assert counts.sum() == n and counts.min() >= min_count
    routes = split_routes(perm, counts)
    for j, i in enumerate(problem.pinned_machine.tolist()):
        if i >= 0:
            assert routes[i][0] == j, f"task {j} pinned to {i} but routes are {routes}"
    assert pins_hold(perm, counts, pins_of(problem))
    assert len(routes) == m


def slow_value(problem, routes, objective):
    """The objective from the problem's own arrays, in plain Python."""
    shares, lengths = [], []
    for i, route in enumerate(routes):
        mc = problem.machines[i]
        if not route:
            shares.append(0.0)
            lengths.append(0.0)
            continue
        s = problem.start_dist[i, route[0]] + problem.end_dist[i, route[-1]]
        s += sum(problem.dist[a, b] for a, b in itertools.pairwise(route))
        drive = s / (1000.0 * mc.road_speed_kmh)
        turn_h = sum(problem.turns[i, j] for j in route) * mc.turn_time_h
        work_h = sum(problem.work_hours[i, j] for j in route)
        lengths.append(s)
        if objective in (Objective.DISTANCE, Objective.MINMAX):
            shares.append(s)
        elif objective == Objective.FUEL:
            shares.append((drive + turn_h) * mc.road_fuel_lh + work_h * mc.work_fuel_lh)
        else:
            shares.append(problem.ready_h[i] + drive + turn_h + work_h)
    if objective in (Objective.MAKESPAN, Objective.MINMAX):
        return max(shares)
    return sum(shares)


@SETTINGS
@given(pinned_cases(min_count=0) | pinned_cases(min_count=1))
def test_repair_puts_every_pin_first_and_loses_nothing(case):
    _, problem, perm, counts = case
    min_count = problem.min_tasks_per_machine
    repair_pins(perm, counts, pins_of(problem), min_count)
    assert_valid_and_pinned(problem, perm, counts, min_count)
    before = (perm.copy(), counts.copy())
    assert not repair_pins(perm, counts, pins_of(problem), min_count)  # idempotent
    np.testing.assert_array_equal(perm, before[0])
    np.testing.assert_array_equal(counts, before[1])


@SETTINGS
@given(pinned_cases(), st.sampled_from(["ox", "pmx", "swap", "insert", "two_opt"]))
def test_every_genetic_operator_then_repair_keeps_pins(case, kind):
    state, problem, perm, counts = case
    pins = pins_of(problem)
    repair_pins(perm, counts, pins, 1)
    n, m = perm.size, counts.size
    for _ in range(5):
        if kind in ("ox", "pmx"):
            other = np.random.default_rng(int(perm[0])).permutation(n).astype(np.int64)
            child, child_counts = np.empty(n, np.int64), np.empty(m, np.int64)
            code = ops.OX if kind == "ox" else ops.PMX
            ops.crossover(state, code, perm, other, counts, child, child_counts)
            perm, counts = child, child_counts
        elif kind == "two_opt":
            ops.random_two_opt(state, perm, counts)
        else:
            ops.mutate(state, ops.SWAP if kind == "swap" else ops.INSERT, perm, counts, 1, True)
        repair_pins(perm, counts, pins, 1)
        assert_valid_and_pinned(problem, perm, counts, 1)


@SETTINGS
@given(pinned_cases(min_count=0) | pinned_cases(), st.sampled_from(list(Objective)))
def test_local_search_keeps_pins_and_reports_true_costs(case, objective):
    state, problem, perm, counts = case
    min_count = problem.min_tasks_per_machine
    pins = pins_of(problem)
    repair_pins(perm, counts, pins, min_count)
    tables = CostTables.of(problem).kernel_args()
    m = counts.size
    route = np.empty(m)
    before = evaluate(perm, counts, int(objective), tables, route)
    for k in (0, 4):  # circle modification, then the neighbour-list 2-opt
        nn = nearest_neighbours(problem.dist, 4)[:, :k]
        cost = polish(state, perm, counts, int(objective), tables, 20, route, nn, pins, min_count)
        assert_valid_and_pinned(problem, perm, counts, min_count)
        assert cost <= before + 1e-9 * max(1.0, before)
        before = cost
    nn = nearest_neighbours(problem.dist, 4)
    improve_allocation(perm, counts, int(objective), tables, nn, min_count, 20, pins)
    assert_valid_and_pinned(problem, perm, counts, min_count)
    after = evaluate(perm, counts, int(objective), tables, route)
    assert after <= before + 1e-9 * max(1.0, before)
    routes = split_routes(perm, counts)
    tie = 0.0
    if objective in (Objective.MAKESPAN, Objective.MINMAX):
        tie = 1e-9 * figures(problem, routes).distance_m
    assert after == pytest.approx(slow_value(problem, routes, objective) + tie, rel=1e-9)


@SETTINGS
@given(pinned_cases(min_count=0) | pinned_cases(), st.sampled_from(list(Objective)))
def test_optimal_split_with_pins_is_the_best_pinned_cut(case, objective):
    _, problem, perm, counts = case
    if problem.num_tasks > 9:
        return
    min_count = problem.min_tasks_per_machine
    pins = pins_of(problem)
    repair_pins(perm, counts, pins, min_count)
    tables = CostTables.of(problem).kernel_args()
    n, m = perm.size, counts.size
    route = np.empty(m)
    best = np.inf
    for cuts in itertools.combinations_with_replacement(range(n + 1), m - 1):
        trial = np.diff(np.array((0, *cuts, n))).astype(np.int64)
        if trial.min() < min_count or not pins_hold(perm, trial, pins):
            continue
        best = min(best, evaluate(perm, trial, int(objective), tables, route))
    split = counts.copy()
    optimal_split(perm, split, int(objective), tables, min_count, pins)
    assert_valid_and_pinned(problem, perm, split, min_count)
    assert evaluate(perm, split, int(objective), tables, route) <= best + 1e-6 * max(1.0, best)


@pytest.mark.parametrize("algorithm", ["ighoa", "ga"])
@pytest.mark.parametrize("objective", list(Objective))
def test_solver_results_keep_pins_with_true_costs(algorithm, objective):
    for seed in range(3):
        problem = pinned_problem(12, 3, seed, min_count=seed % 2)
        params = IGHOAParams(population=20) if algorithm == "ighoa" else GAParams(20)
        result = solve(problem, objective, algorithm, stop_after(25), seed=seed, params=params)
        perm = np.array([j for r in result.routes for j in r], dtype=np.int64)
        counts = np.array([len(r) for r in result.routes], dtype=np.int64)
        assert_valid_and_pinned(problem, perm, counts, problem.min_tasks_per_machine)
        expected = slow_value(problem, [list(r) for r in result.routes], objective)
        assert result.cost == pytest.approx(expected, rel=1e-9)


def test_warm_start_is_repaired_for_pins_and_bad_pins_are_named():
    unpinned = dataclasses.replace(pinned_problem(6, 2, 4), pinned_machine=np.zeros(0, np.int64))
    problem = unpinned.pinned({5: 1})
    result = solve(problem, "distance", "ga", MaxGenerations(0), initial_routes=[[5, 0, 1], [2]])
    assert result.routes[1][0] == 5
    with pytest.raises(ProblemError, match="has two pinned tasks"):
        problem.pinned({0: 1, 1: 1})
    with pytest.raises(ProblemError, match="pinned to machine 7"):
        problem.pinned({0: 7})
