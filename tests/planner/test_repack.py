"""planner.repack: neighbouring routes re-packed by a small integer program."""

import dataclasses

import numpy as np
import pytest
from helpers.chromosomes import NO_PINS, assert_valid, problem_for
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.cost import OVERLOAD, CostTables, Objective, evaluate
from planner.hybrid import HybridParams
from planner.local_search import nearest_neighbours
from planner.population import random_counts
from planner.repack import _insertions_m, _linear_hours, _removals_m, _routes, repack
from planner.rng import make_state
from planner.solve import solve, stop_after

MAKESPAN = int(Objective.MAKESPAN)


def _setting(n, m, seed, min_count=1):
    """A problem with weighed machines, a random chromosome, its route hours, neighbours."""
    problem = problem_for(n, m, seed, min_count=min_count)
    rng = np.random.default_rng(seed)
    weights = rng.uniform(0.2, 3.0, m)
    tables = dataclasses.replace(CostTables.of(problem), hour_weights=m * weights / weights.sum())
    tables = tables.kernel_args()
    perm = rng.permutation(n).astype(np.int64)
    counts = np.empty(m, dtype=np.int64)
    random_counts(make_state(seed), n, m, min_count, counts)
    hours = np.empty(m)
    evaluate(perm, counts, MAKESPAN, tables, hours)
    return tables, perm, counts, hours, nearest_neighbours(problem.dist, 5)


def _figure(hours, target, weights):
    return float(np.sum(weights * hours + OVERLOAD * np.clip(hours - target, 0.0, None)))


@given(
    st.integers(4, 40), st.integers(2, 6), st.integers(0, 2**31), st.floats(0.9, 1.1),
    st.floats(1.0, 1.2), st.integers(2, 4), st.integers(0, 1),
)  # fmt: skip
@settings(max_examples=40, deadline=None, derandomize=True)
def test_it_lowers_the_squeezes_figure_by_what_it_says_and_keeps_routes_within_the_limit(
    n, m, seed, target_share, limit_share, size, min_count
):
    m = min(m, n)
    tables, perm, counts, hours, neighbours = _setting(n, m, seed, min_count)
    target, limit = target_share * hours.max(), limit_share * hours.max()
    route_cost = hours.copy()
    gained = repack(
        make_state(seed), perm, counts, route_cost, MAKESPAN, tables, neighbours, NO_PINS(n),
        min_count, target, limit, 5, size,
    )  # fmt: skip
    assert_valid(perm, counts, n, m, min_count)
    after = np.empty(m)
    evaluate(perm, counts, MAKESPAN, tables, after)
    assert np.array_equal(after, route_cost)  # the route costs it keeps are the routes'
    assert gained >= 0.0
    before_figure = _figure(hours, target, tables[8])
    assert before_figure - _figure(after, target, tables[8]) == pytest.approx(gained, abs=1e-9)
    if gained > 0.0:
        assert after.max() <= limit


def test_a_random_plan_is_repacked_and_the_same_seed_gives_the_same_answer():
    """Re-packing has much to give a random plan; its draws follow its seed."""
    runs = []
    for seed in (3, 3, 4):
        tables, perm, counts, hours, neighbours = _setting(60, 5, 1)
        gained = repack(
            make_state(seed), perm, counts, hours, MAKESPAN, tables, neighbours, NO_PINS(60),
            1, hours.max(), hours.max(), 20, 2,
        )  # fmt: skip
        runs.append((gained, perm, counts))
    assert runs[0][0] > 0.0
    assert np.array_equal(runs[0][1], runs[1][1]) and np.array_equal(runs[0][2], runs[1][2])
    assert not np.array_equal(runs[0][1], runs[2][1])


def test_the_linear_model_is_exact_for_one_field_in_or_out():
    """A field's price in the linear model is what adding it at its best place, or taking
    it out, changes the route's hours by (the model errs only when several change)."""
    tables, perm, counts, hours, _ = _setting(30, 3, 2)
    routes = _routes(perm, counts)
    fields = np.array(sorted(routes[0] + routes[1]), dtype=np.int64)
    cost, base = _linear_hours([0, 1], routes, fields, hours, tables)
    for a, i in enumerate((0, 1)):
        assert base[a] + sum(cost[a, list(fields).index(j)] for j in routes[i]) == pytest.approx(
            hours[i]
        )
        for k, j in enumerate(fields):
            trial = [list(r) for r in routes]
            if j in routes[i]:
                trial[i].remove(j)
                expected = hours[i] - cost[a, k]
            else:
                place = int(np.argmin(_insertions_m(i, routes[i], [j], *tables[:3])[0]))
                trial[i].insert(place, j)
                expected = hours[i] + cost[a, k]
            got = np.empty(3)
            evaluate(
                np.array([t for r in trial for t in r], dtype=np.int64),
                np.array([len(r) for r in trial], dtype=np.int64), MAKESPAN, tables, got,
            )  # fmt: skip
            assert got[i] == pytest.approx(expected)


def test_removals_of_a_one_field_route_save_its_whole_road():
    tables, perm, counts, _, _ = _setting(10, 2, 5)
    dist, start, end = tables[:3]
    assert _removals_m(0, [3], dist, start, end)[0] == pytest.approx(start[0, 3] + end[0, 3])


def test_a_pinned_field_stays_first_on_its_machine():
    n, m = 40, 4
    tables, perm, counts, hours, neighbours = _setting(n, m, 7)
    pins = NO_PINS(n)
    begin = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for i in range(m):
        pins[perm[begin[i]]] = i
    gained = repack(
        make_state(1), perm, counts, hours, MAKESPAN, tables, neighbours, pins, 1,
        hours.max(), 1.5 * hours.max(), 30, 2,
    )  # fmt: skip
    assert gained > 0.0
    begin = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for i in range(m):
        assert pins[perm[begin[i]]] == i


def _ten_generations(**params):
    problem = problem_for(60, 4, 1, min_count=0)
    return solve(
        problem, "makespan", "hybrid", stop_after(10), seed=2, params=HybridParams(**params)
    )


def test_in_the_solver_the_squeezes_walk_is_repacked_and_the_run_keeps_to_its_seed():
    without, with_, again = (_ten_generations(repack_groups=g) for g in (0, 20, 20))
    assert without.stats["repack_gains"] == 0
    assert with_.stats["repack_gains"] > 0
    assert with_.history != without.history
    assert again.routes == with_.routes and again.history == with_.history


@pytest.mark.parametrize(("name", "value"), [("repack_groups", -1), ("repack_size", 1)])
def test_the_repack_settings_are_checked(name, value):
    with pytest.raises(ValueError, match=name):
        HybridParams(**{name: value})
