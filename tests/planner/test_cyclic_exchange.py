"""The cyclic exchange (planner.cyclic_exchange): its assignment solver, its moves, and its place in
the solver (the answer's roads under the makespan)."""

import itertools

import numpy as np
import pytest
from helpers.chromosomes import NO_PINS, SETTINGS, assert_valid, problem_for
from hypothesis import given
from hypothesis import strategies as st

from planner.cost import CostTables, Objective, evaluate
from planner.cyclic_exchange import INFEASIBLE, assignment, cyclic_exchange
from planner.hybrid import HybridParams
from planner.population import random_counts
from planner.rng import make_state
from planner.solve import solve, stop_after


@given(st.integers(1, 6), st.integers(0, 2**31), st.booleans())
@SETTINGS
def test_the_assignment_is_the_cheapest_permutation(n, seed, forbid):
    rng = np.random.default_rng(seed)
    costs = rng.uniform(0.0, 100.0, size=(n, n)).round(1)
    if forbid:  # as the exchange writes it: off the diagonal, some pairs not allowed
        costs[(rng.uniform(size=(n, n)) < 0.4) & ~np.eye(n, dtype=bool)] = INFEASIBLE
    given_to = assignment(costs)
    assert sorted(given_to.tolist()) == list(range(n))
    best = min(sum(costs[i, p[i]] for i in range(n)) for p in itertools.permutations(range(n)))
    assert sum(costs[i, given_to[i]] for i in range(n)) == pytest.approx(best, rel=1e-12)


def _chromosome(problem, seed):
    rng = np.random.default_rng(seed)
    perm = rng.permutation(problem.num_tasks).astype(np.int64)
    counts = np.empty(problem.num_machines, dtype=np.int64)
    random_counts(make_state(seed), problem.num_tasks, problem.num_machines, 1, counts)
    return perm, counts


def _hours_and_road(perm, counts, tables):
    hours = np.zeros(counts.shape[0])
    road = np.zeros(counts.shape[0])
    evaluate(perm, counts, int(Objective.MAKESPAN), tables, hours)
    evaluate(perm, counts, int(Objective.DISTANCE), tables, road)
    return hours, road


@given(st.integers(2, 40), st.integers(1, 6), st.integers(0, 2**31), st.floats(0.9, 1.2))
@SETTINGS
def test_the_exchange_saves_what_it_says_and_keeps_every_route_within_the_cap(
    n, m, seed, cap_share
):
    m = min(m, n)
    problem = problem_for(n, m, seed)
    tables = CostTables.of(problem).kernel_args()
    perm, counts = _chromosome(problem, seed)
    before_counts = counts.copy()
    hours, road = _hours_and_road(perm, counts, tables)
    cap = hours.max() * cap_share
    saved = cyclic_exchange(make_state(seed), perm, counts, tables, NO_PINS(n), cap, 30)
    assert_valid(perm, counts, n, m)
    assert np.array_equal(counts, before_counts)  # one task out, one in, every route
    after_hours, after_road = _hours_and_road(perm, counts, tables)
    assert saved >= 0.0
    assert road.sum() - after_road.sum() == pytest.approx(saved, rel=1e-9, abs=1e-6)
    # No route goes above the cap, nor above where it was if it was over it already.
    assert np.all(after_hours <= np.maximum(cap, hours) + 1e-9)


def test_the_exchange_finds_cycles_where_pairs_are_jammed_and_follows_its_seed():
    problem = problem_for(60, 5, 3)
    tables = CostTables.of(problem).kernel_args()
    perm, counts = _chromosome(problem, 3)
    hours, road = _hours_and_road(perm, counts, tables)
    runs = []
    for _ in range(2):
        p, c = perm.copy(), counts.copy()
        saved = cyclic_exchange(make_state(7), p, c, tables, NO_PINS(60), hours.max(), 200)
        runs.append((saved, p))
    assert runs[0][0] > 0.05 * road.sum()  # a random plan has much to give
    assert np.array_equal(runs[0][1], runs[1][1])  # same seed, same answer
    other = perm.copy()
    cyclic_exchange(make_state(8), other, counts.copy(), tables, NO_PINS(60), hours.max(), 200)
    assert not np.array_equal(other, runs[0][1])


def test_a_pinned_task_neither_moves_nor_has_one_put_before_it():
    problem = problem_for(40, 4, 5)
    tables = CostTables.of(problem).kernel_args()
    perm, counts = _chromosome(problem, 5)
    pins = NO_PINS(40)
    begin = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for i in (0, 2):  # the first tasks of two routes pinned to them
        pins[perm[begin[i]]] = i
    hours, _ = _hours_and_road(perm, counts, tables)
    saved = cyclic_exchange(make_state(1), perm, counts, tables, pins, 2.0 * hours.max(), 300)
    assert saved > 0.0
    begin = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for i in (0, 2):
        assert pins[perm[begin[i]]] == i


def test_in_the_solver_the_answer_keeps_the_elites_makespan_and_drives_less():
    """The exchanges work on a copy with its own random stream: the elite's search goes
    exactly as without them, and the answer is that makespan with less road."""
    problem = problem_for(80, 8, 2, min_count=0)
    runs = {
        rounds: solve(
            problem,
            "makespan",
            "hybrid",
            stop_after(8),
            seed=2,
            params=HybridParams(cyclic_exchange_rounds=rounds),
        )
        for rounds in (0, 1000)
    }
    without, with_ = runs[0], runs[1000]
    assert without.history == with_.history  # the same search
    assert with_.figures.makespan_h <= without.figures.makespan_h + 1e-12
    assert with_.figures.distance_m < without.figures.distance_m
    assert with_.stats["cyclic_exchange_gains"] > 0


def test_the_cyclic_exchange_rounds_are_checked():
    with pytest.raises(ValueError, match="cyclic_exchange_rounds"):
        HybridParams(cyclic_exchange_rounds=-1)
