"""The cyclic exchange (planner.cyclic_exchange): its assignment solver, its moves under both of
its figures (the road, the squeeze's weighed hours), and its places in the solver (the answer's
roads under the makespan; the squeeze's walk)."""

import dataclasses
import itertools

import numpy as np
import pytest
from helpers.chromosomes import NO_PINS, SETTINGS, assert_valid, problem_for
from hypothesis import given
from hypothesis import strategies as st

from planner.cost import OVERLOAD, CostTables, Objective, evaluate
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


def _chromosome(problem, seed, min_count=1):
    rng = np.random.default_rng(seed)
    perm = rng.permutation(problem.num_tasks).astype(np.int64)
    counts = np.empty(problem.num_machines, dtype=np.int64)
    random_counts(make_state(seed), problem.num_tasks, problem.num_machines, min_count, counts)
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


def _weighed_tables(problem, seed, ready=False):
    """The problem's tables with hour weights of the machines' own (a mean of one), as the
    relaxation's duals make them; with ``ready``, some machines busy for a while before
    their route starts (a re-plan: an empty route then costs no hours, a route given its
    first field costs that wait too)."""
    rng = np.random.default_rng(seed)
    weights = rng.uniform(0.2, 3.0, problem.num_machines)
    weights *= problem.num_machines / weights.sum()
    tables = dataclasses.replace(CostTables.of(problem), hour_weights=weights)
    if ready:
        busy = rng.uniform(0.0, 2.0, problem.num_machines) * (rng.uniform(size=weights.size) < 0.6)
        tables = dataclasses.replace(tables, ready_h=busy)
    return tables.kernel_args()


def _squeezed(tables, hours, road, target, road_weight):
    """The exchange's figure under the squeeze (planner.cyclic_exchange), written out: the
    weighed hours, each hour past the target OVERLOAD times more, and the weighed hours of
    driving ``road_weight`` times more."""
    weights, road_h = tables[8], tables[3]
    squeeze = np.sum(weights * hours + OVERLOAD * np.clip(hours - target, 0.0, None))
    return squeeze + road_weight * np.sum(weights * road * road_h)


@given(
    st.integers(2, 40), st.integers(1, 6), st.integers(0, 2**31), st.floats(0.9, 1.2),
    st.floats(0.95, 1.0), st.sampled_from([0.0, 1.0, 2.5]), st.sampled_from([0.0, 0.3, 0.7]),
    st.integers(0, 1), st.booleans(),
)  # fmt: skip
@SETTINGS
def test_under_the_squeeze_it_lowers_the_figure_by_what_it_says_within_the_cap(
    n, m, seed, cap_share, target_share, road_weight, empty_share, min_count, ready
):
    m = min(m, n)
    problem = problem_for(n, m, seed, min_count=min_count)
    tables = _weighed_tables(problem, seed, ready)
    perm, counts = _chromosome(problem, seed, min_count)
    before_counts = counts.copy()
    hours, road = _hours_and_road(perm, counts, tables)
    cap = hours.max() * cap_share
    target = hours.max() * target_share
    saved = cyclic_exchange(
        make_state(seed), perm, counts, tables, NO_PINS(n), cap, 30, target=target,
        road_weight=road_weight, empty_share=empty_share, min_count=min_count,
    )  # fmt: skip
    assert_valid(perm, counts, n, m, min_count)
    if empty_share == 0.0:
        assert np.array_equal(counts, before_counts)  # one task out, one in, every route
    after_hours, after_road = _hours_and_road(perm, counts, tables)
    assert saved >= 0.0
    before = _squeezed(tables, hours, road, target, road_weight)
    after = _squeezed(tables, after_hours, after_road, target, road_weight)
    assert before - after == pytest.approx(saved, rel=1e-9, abs=1e-6)
    assert np.all(after_hours <= np.maximum(cap, hours) + 1e-9)


def test_empty_picks_hand_a_field_on_along_a_path_from_a_full_route():
    """One route with most of the fields, the cap at its hours: no cycle can take a field
    off it for good, a path can (each route on it giving one on and the last taking one);
    without empty picks the sizes stay."""
    problem = problem_for(40, 4, 6, min_count=0)
    tables = _weighed_tables(problem, 6)
    perm = np.random.default_rng(6).permutation(40).astype(np.int64)
    counts = np.array([28, 4, 4, 4], dtype=np.int64)
    hours, _ = _hours_and_road(perm, counts, tables)
    target = 0.5 * hours.max()
    for share, sizes_change in ((0.0, False), (0.3, True)):
        p, c = perm.copy(), counts.copy()
        saved = cyclic_exchange(
            make_state(2), p, c, tables, NO_PINS(40), hours.max(), 200, target=target,
            empty_share=share,
        )  # fmt: skip
        assert saved > 0.0
        assert (c[0] < 28) == sizes_change
        assert_valid(p, c, 40, 4, 0)


def test_under_the_squeeze_the_fields_go_to_the_machines_that_do_them_in_fewer_weighed_hours():
    """Under the squeeze the exchange goes by the machines' weighed hours, not by the road
    (a search of its own), never past the cap, and keeps to its seed."""
    problem = problem_for(60, 5, 4)
    tables = _weighed_tables(problem, 4)
    perm, counts = _chromosome(problem, 4)
    hours, road = _hours_and_road(perm, counts, tables)
    target = hours.max()
    runs = []
    for _ in range(2):
        p, c = perm.copy(), counts.copy()
        saved = cyclic_exchange(
            make_state(5), p, c, tables, NO_PINS(60), target, 200, target=target
        )
        runs.append((saved, p, c))
    saved, p, c = runs[0]
    after_hours, _ = _hours_and_road(p, c, tables)
    assert saved > 0.0
    assert (tables[8] * after_hours).sum() < (tables[8] * hours).sum()
    assert after_hours.max() <= target + 1e-9
    assert np.array_equal(runs[1][1], p)  # same seed, same answer
    by_road = perm.copy()
    cyclic_exchange(make_state(5), by_road, counts.copy(), tables, NO_PINS(60), target, 200)
    assert not np.array_equal(by_road, p)  # the two figures are two searches


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


@pytest.mark.parametrize(("squeeze", "empty_share"), [(False, 0.0), (True, 0.0), (True, 0.3)])
def test_a_pinned_task_neither_moves_nor_has_one_put_before_it(squeeze, empty_share):
    problem = problem_for(40, 4, 5)
    tables = _weighed_tables(problem, 5)
    perm, counts = _chromosome(problem, 5)
    pins = NO_PINS(40)
    begin = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for i in (0, 2):  # the first tasks of two routes pinned to them
        pins[perm[begin[i]]] = i
    hours, _ = _hours_and_road(perm, counts, tables)
    target = hours.max() if squeeze else 0.0  # the squeeze's figure, or the road
    saved = cyclic_exchange(
        make_state(1), perm, counts, tables, pins, 2.0 * hours.max(), 300, target=target,
        empty_share=empty_share,
    )  # fmt: skip
    assert saved > 0.0
    begin = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for i in (0, 2):
        assert pins[perm[begin[i]]] == i


def _eight_generations(problem_seed, **params):
    """Eight generations of hybrid under the makespan on a farm of 80 fields and 8 machines
    (``problem_seed``), seed 2, with these ``params``."""
    problem = problem_for(80, 8, problem_seed, min_count=0)
    return solve(
        problem, "makespan", "hybrid", stop_after(8), seed=2, params=HybridParams(**params)
    )


def test_in_the_solver_the_answer_keeps_the_elites_makespan_and_drives_less():
    """The exchanges work on a copy with its own random stream: the elite's search goes
    exactly as without them, and the answer is that makespan with less road."""
    without, with_ = (_eight_generations(2, cyclic_exchange_rounds=r) for r in (0, 1000))
    assert without.history == with_.history  # the same search
    assert with_.figures.makespan_h <= without.figures.makespan_h + 1e-12
    # never more road; less when the last copy found road to save, which depends on the run
    assert with_.figures.distance_m <= without.figures.distance_m
    assert with_.stats["cyclic_exchange_gains"] > 0


def test_the_squeezes_walk_is_handed_round_and_the_run_keeps_to_its_seed():
    without, with_, again = (
        _eight_generations(2, squeeze_exchange_rounds=r) for r in (0, 1000, 1000)
    )
    assert without.stats["squeeze_exchange_gains"] == 0
    assert with_.stats["squeeze_exchange_gains"] > 0
    assert with_.history != without.history  # the search is not the same one
    assert again.routes == with_.routes and again.history == with_.history


@pytest.mark.parametrize("name", ["cyclic_exchange_rounds", "squeeze_exchange_rounds"])
def test_the_cyclic_exchange_rounds_are_checked(name):
    with pytest.raises(ValueError, match=name):
        HybridParams(**{name: -1})
