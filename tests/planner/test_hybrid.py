"""planner.hybrid's operators: valid chromosomes, true deltas, same seed same answer."""

import numpy as np
import pytest
from helpers.chromosomes import NO_PINS, SETTINGS, assert_valid, chromosomes, problem_for
from hypothesis import given
from hypothesis import strategies as st

import planner.hybrid
from planner.cost import (
    OVERLOAD,
    TIE_BREAK,
    CostTables,
    Objective,
    evaluate,
    figures,
    fleet_value,
    split_routes,
    squeeze_figure,
)
from planner.hybrid import (
    HybridParams,
    giant_tour,
    ils_step,
    or_opt,
    or_opt_routes,
    perturb,
    route_ils,
    sweep,
    sweep_order,
    tour_ils,
)
from planner.local_search import nearest_neighbours
from planner.moves import MOVES
from planner.pins import pins_hold, repair_pins
from planner.problem import Machine, Problem, Task
from planner.rng import make_state
from planner.solve import solve, stop_after, warm_up


def route_lengths(perm, counts, tables):
    out = np.empty(counts.size)
    evaluate(perm, counts, int(Objective.MINMAX), tables, out)
    return out


@SETTINGS
@given(chromosomes(), st.integers(1, 8))
def test_or_opt_keeps_validity_and_its_gain_is_the_true_shortening(case, k):
    state, perm, counts = case
    n, m = perm.size, counts.size
    problem = problem_for(n, m, int(perm[0]) + 3 * n)
    tables = CostTables.of(problem).kernel_args()
    nn = nearest_neighbours(problem.dist, k)
    before = route_lengths(perm, counts, tables)
    gain = or_opt_routes(perm, counts, *tables[:3], nn, NO_PINS(n))
    assert_valid(perm, counts, n, m)
    after = route_lengths(perm, counts, tables)
    assert gain >= 0.0
    assert before.sum() - after.sum() == pytest.approx(gain, rel=1e-9, abs=1e-6)
    assert np.all(after <= before + 1e-6)  # each route on its own never lengthens


def test_or_opt_moves_a_misplaced_task_home_and_keeps_a_pinned_first():
    # Tasks on a line, one visited out of order; the depot at x = 0.
    xs = [1.0, 2.0, 6.0, 3.0, 4.0, 5.0]
    problem = Problem.build(
        [Machine("m", 1.0, 1.0, 1.0, 0.0, 1.0, 1.0)],
        [Task(f"t{j}", x, 0.0) for j, x in enumerate(xs)],
        (0.0, 0.0),
    )
    tables = CostTables.of(problem).kernel_args()
    perm = np.arange(6, dtype=np.int64)
    gain = or_opt(perm, 0, 6, 0, *tables[:3], nearest_neighbours(problem.dist, 3), 0)
    # 16 long before; out and back along the line (12) after: task 2 (x = 6) moved on.
    assert gain == pytest.approx(4.0) and perm[:4].tolist() == [0, 1, 3, 4]
    perm = np.array([2, 0, 1, 3, 4, 5], dtype=np.int64)  # task 2 pinned first
    or_opt(perm, 0, 6, 0, *tables[:3], nearest_neighbours(problem.dist, 3), 1)
    assert perm[0] == 2 and sorted(perm.tolist()) == list(range(6))


@SETTINGS
@given(chromosomes(min_count=0), st.integers(1, 6), st.booleans(), st.integers(0, 1))
def test_perturb_keeps_validity_minimum_and_pins(case, strength, focus, min_count):
    state, perm, counts = case
    n, m = perm.size, counts.size
    if min_count and counts.min() < 1:
        return
    pins = NO_PINS(n)
    pins[int(perm[0])] = 0  # the first task of route 0 (or of a later one) pinned there
    repair_pins(perm, counts, pins, min_count)
    nn = nearest_neighbours(problem_for(n, m, n).dist, 4)
    moved = np.empty(strength, dtype=np.int64)
    route_cost = np.arange(m, dtype=np.float64)
    done = perturb(state, perm, counts, route_cost, strength, focus, min_count, pins, nn, moved)
    assert_valid(perm, counts, n, m, min_count)
    assert pins_hold(perm, counts, pins)
    assert 0 <= done <= strength and set(moved[:done]) <= set(range(n))
    assert pins[moved[:done]].max(initial=-1) < 0  # the pinned task never moves


@pytest.mark.parametrize("over", [0.0, 1.02])
@pytest.mark.parametrize("focus", [False, True])
@pytest.mark.parametrize("ruin", [0, 4])
@pytest.mark.parametrize("objective", list(Objective))
def test_ils_step_reports_the_true_cost_and_never_worsens(objective, ruin, focus, over):
    problem = problem_for(25, 3, 5)
    tables = CostTables.of(problem).kernel_args()
    rng = np.random.default_rng(1)
    perm = rng.permutation(25).astype(np.int64)
    counts = np.array([8, 8, 9], dtype=np.int64)
    route = np.empty(3)
    cost = evaluate(perm, counts, int(objective), tables, route)
    # A cap (min-max objectives): the costs, given and returned, count the figure as at
    # least it (planner.cost.fleet_value).
    cap = over * route.max() if objective in (Objective.MAKESPAN, Objective.MINMAX) else 0.0
    cost += max(0.0, cap - route.max())
    nn = nearest_neighbours(problem.dist, 6)
    new, walk = ils_step(
        make_state(2), perm, counts, route, cost, perm.copy(), counts.copy(), route.copy(),
        cost, int(objective), tables, nn, 1, NO_PINS(25), 10, 3, np.inf, 7, True, 0.01, ruin,
        ruin > 0, focus, cap,
    )  # fmt: skip
    assert new <= walk + 1e-9 and walk <= cost * 1.01
    assert_valid(perm, counts, 25, 3)
    check = np.empty(3)
    true = evaluate(perm, counts, int(objective), tables, check)
    assert new == pytest.approx(true + max(0.0, cap - check.max()), rel=1e-12)
    assert new <= cost
    np.testing.assert_allclose(route, check)


def test_the_squeeze_adds_up_the_routes_and_counts_each_hour_over_the_target_more():
    values, lengths = np.array([5.0, 10.0, 12.5]), np.array([1000.0, 2000.0, 500.0])
    alike = np.ones(3)
    assert squeeze_figure(values, 10.0, alike) == pytest.approx(27.5 + OVERLOAD * 2.5)
    assert squeeze_figure(values, 20.0, alike) == pytest.approx(27.5)
    # Each route's hours count by its machine's weight; an hour over the target by OVERLOAD.
    weighed = np.array([2.0, 0.5, 0.5])
    assert squeeze_figure(values, 10.0, weighed) == pytest.approx(21.25 + OVERLOAD * 2.5)
    # fleet_value's cap < 0 is the squeeze towards -cap, with the distance tie-breaker.
    squeezed = fleet_value(int(Objective.MAKESPAN), values, lengths, -10.0, alike)
    assert squeezed == pytest.approx(27.5 + OVERLOAD * 2.5 + TIE_BREAK * 3500.0, rel=1e-12)
    plain = fleet_value(int(Objective.MAKESPAN), values, lengths, 0.0, weighed)
    assert plain == pytest.approx(12.5, rel=1e-6)


@pytest.mark.parametrize("pinned", [False, True])
@pytest.mark.parametrize("ruin", [1, 5])
def test_the_squeeze_reports_the_true_costs_never_worsens_and_keeps_pins(ruin, pinned):
    """``ils_step`` with ``squeeze`` (the makespan's ILS): the elite and the walk it
    returns are what their arrays cost under the makespan, and the elite only improves."""
    problem = problem_for(25, 3, 5)
    tables = CostTables.of(problem).kernel_args()
    perm = np.random.default_rng(1).permutation(25).astype(np.int64)
    counts = np.array([8, 8, 9], dtype=np.int64)
    pins = NO_PINS(25)
    if pinned:  # each route's first task stays first with its machine (a re-plan)
        pins[perm[[0, 8, 16]]] = [0, 1, 2]
    route = np.empty(3)
    cost = evaluate(perm, counts, int(Objective.MAKESPAN), tables, route)
    walk_perm, walk_counts, walk_route = perm.copy(), counts.copy(), route.copy()
    nn = nearest_neighbours(problem.dist, 6)
    new, walk = ils_step(
        make_state(2), perm, counts, route, cost, walk_perm, walk_counts, walk_route, cost,
        int(Objective.MAKESPAN), tables, nn, 1, pins, 30, 3, np.inf, 7, False, 0.03, ruin,
        False, True, 0.0, 0.002,
    )  # fmt: skip
    assert new < cost  # a random plan leaves room
    for p, c, r, value in ((perm, counts, route, new), (walk_perm, walk_counts, walk_route, walk)):
        assert_valid(p, c, 25, 3)
        check = np.empty(3)
        assert value == pytest.approx(evaluate(p, c, int(Objective.MAKESPAN), tables, check))
        np.testing.assert_allclose(r, check)
        assert pins_hold(p, c, pins)
    assert new <= walk + 1e-12


def _a_makespan_elite():
    """A 40 x 4 problem, its kernels' tables, and 20 generations' plan under the makespan
    as a chromosome with its routes' figures and its cost."""
    problem = problem_for(40, 4, 7)
    tables = CostTables.of(problem).kernel_args()
    best = solve(problem, "makespan", "hybrid", stop_after(20), seed=1)
    perm = np.array([j for r in best.routes for j in r], dtype=np.int64)
    counts = np.array([len(r) for r in best.routes], dtype=np.int64)
    route = np.empty(4)
    cost = evaluate(perm, counts, int(Objective.MAKESPAN), tables, route)
    return problem, tables, best, perm, counts, route, cost


def test_a_loosened_squeeze_walks_past_the_makespan_and_the_elite_only_improves():
    """A squeeze step below 0 puts the target above the elite's makespan: the walk may end
    a route past the makespan where the weighed hours fall (strategic oscillation: the
    steps above 0 then push it back under); the elite only improves, and the costs
    returned are what the arrays cost."""
    problem, tables, best, perm, counts, route, cost = _a_makespan_elite()
    weights = tables[8]
    loose = -0.05
    target = cost * (1.0 - loose)
    start_figure = squeeze_figure(route, target, weights)
    walk_perm, walk_counts, walk_route = perm.copy(), counts.copy(), route.copy()
    nn = nearest_neighbours(problem.dist, 6)
    new, walk = ils_step(
        make_state(3), perm, counts, route, cost, walk_perm, walk_counts, walk_route, cost,
        int(Objective.MAKESPAN), tables, nn, 1, NO_PINS(40), 200, 3, np.inf, 7, True, 0.03, 11,
        False, True, 0.0, loose,
    )  # fmt: skip
    assert new <= cost
    assert walk > new  # past the elite's makespan
    assert squeeze_figure(walk_route, new * (1.0 - loose), weights) < start_figure
    for p, c, r, value in ((perm, counts, route, new), (walk_perm, walk_counts, walk_route, walk)):
        assert_valid(p, c, 40, 4)
        check = np.empty(4)
        assert value == pytest.approx(evaluate(p, c, int(Objective.MAKESPAN), tables, check))
        np.testing.assert_allclose(r, check)


def test_under_a_cap_the_walk_keeps_to_the_cap_and_to_the_elites_road():
    """``ils_step`` with a makespan cap: the walk's record-to-record ``accept`` is a share of
    the distance term (what a cost has above the cap), so the walk keeps to plans within
    the cap (or as far over it as a few metres of road weigh) whose road is within
    ``accept`` of the elite's; the whole cost's share would let it wander 3 % over the
    cap whatever its road."""
    problem, tables, best, perm, counts, route, cost = _a_makespan_elite()
    cap = float(route.max())  # the deadline is the elite's makespan: no room below it
    capped = cost + cap - route.max()
    walk_perm, walk_counts, walk_route = perm.copy(), counts.copy(), route.copy()
    nn = nearest_neighbours(problem.dist, 6)
    new, walk = ils_step(
        make_state(3), perm, counts, route, capped, walk_perm, walk_counts, walk_route, capped,
        int(Objective.MAKESPAN), tables, nn, 1, NO_PINS(40), 200, 3, np.inf, 7, True, 0.03, 11,
        False, False, cap, 0.0,
    )  # fmt: skip
    walk_figures = figures(problem, split_routes(walk_perm, walk_counts))
    assert new <= capped and route.max() <= cap
    assert walk_figures.makespan_h <= cap + 1e-4
    assert walk_figures.distance_m <= 1.03 * best.figures.distance_m + 1.0  # the elite's at most


@pytest.mark.parametrize("objective", ["distance", "makespan", "minmax"])
def test_hybrid_gives_valid_routes_and_the_same_answer_for_the_same_seed(objective):
    problem = problem_for(20, 3, 11)
    params = HybridParams(
        population=20, ils_steps=3, ils_on_sums=True, moves=MOVES, distance_share=0.2
    )
    a, b = (
        solve(problem, objective, "hybrid", stop_after(15), seed=3, params=params) for _ in range(2)
    )
    assert sorted(j for r in a.routes for j in r) == list(range(20)) and all(a.routes)
    assert a.routes == b.routes and a.history == b.history
    # The best never worsens; under the makespan the last share of the generations may
    # give up to distance_slack of it for road distance (HybridParams.distance_share).
    slack = params.distance_slack if objective == "makespan" else 0.0
    assert all(y <= x * (1 + slack) for x, y in zip(a.history, a.history[1:], strict=False))
    assert max(a.history[:12]) <= a.history[0] and a.history[-1] <= min(a.history) * (1 + slack)
    assert a.cost == pytest.approx(a.figures.value(a.objective))


@pytest.mark.parametrize("objective", ["minmax", "makespan"])
def test_other_routes_are_ordered_again_under_min_max_and_the_answer_repeats(objective):
    """``other_routes``: besides the longest, one route in turn gets the route ILS; the
    best never worsens, the routes stay valid, and the same seed gives the same answer.
    (Without the sweep, whose routes are ordered by that ILS from the start.)"""
    problem = problem_for(240, 3, 5)
    params = HybridParams(population=20, ils_steps=3, route_kicks=20, sweep=False)
    runs = [
        solve(problem, objective, "hybrid", stop_after(6), seed=1, params=params) for _ in (0, 1)
    ]
    a, b = runs
    assert sorted(j for r in a.routes for j in r) == list(range(240)) and all(a.routes)
    assert a.routes == b.routes and a.history == b.history
    assert a.stats["other_gains"] > 0
    assert all(y <= x for x, y in zip(a.history, a.history[1:], strict=False))
    assert a.cost == pytest.approx(a.figures.value(a.objective))
    off = solve(
        problem,
        objective,
        "hybrid",
        stop_after(6),
        seed=1,
        params=HybridParams(
            population=20, ils_steps=3, route_kicks=20, sweep=False, other_routes=False
        ),
    )
    assert off.stats["other_gains"] == 0


@SETTINGS
@given(chromosomes(min_count=0), st.sampled_from(list(Objective)), st.integers(0, 1), st.booleans())
def test_the_giant_tour_and_the_sweep_give_valid_chromosomes_with_their_pins(
    case, objective, min_count, swept
):
    state, perm, counts = case
    n, m = perm.size, counts.size
    problem = problem_for(n, m, n + 2 * m)
    tables = CostTables.of(problem).kernel_args()
    pins = NO_PINS(n)
    pins[int(perm[-1])] = m - 1  # one task pinned to the last machine
    nn = nearest_neighbours(problem.dist, 5)
    args = (int(objective), tables, nn, min_count, pins, np.inf)
    if swept:
        order = sweep_order(problem)
        assert order is not None and sorted(order.tolist()) == list(range(n))
        sweep(state, perm, counts, order, *args, 20, np.inf)
    else:
        giant_tour(state, perm, counts, *args, 50 * n, np.inf)
    assert_valid(perm, counts, n, m, min_count)
    assert pins_hold(perm, counts, pins)


def test_giant_tour_is_a_good_tour_cut_optimally():
    # Tasks on a circle around the depot: the giant tour goes round it once.
    angles = np.linspace(0.0, 2 * np.pi, 40, endpoint=False)
    problem = Problem.build(
        [Machine(f"m{i}", 1.0, 1.0, 1.0, 0.0, 1.0, 1.0) for i in range(2)],
        [Task(f"t{j}", 100 * np.cos(a), 100 * np.sin(a)) for j, a in enumerate(angles)],
        (0.0, 0.0),
    )
    tables = CostTables.of(problem).kernel_args()
    perm = np.zeros(40, dtype=np.int64)
    counts = np.zeros(2, dtype=np.int64)
    nn = nearest_neighbours(problem.dist, 6)
    giant_tour(
        make_state(1), perm, counts, int(Objective.MINMAX), tables, nn, 1, NO_PINS(40), np.inf,
        4000, np.inf,
    )  # fmt: skip
    route = np.empty(2)
    evaluate(perm, counts, int(Objective.MINMAX), tables, route)
    # Two half circles: 100 out, 19 chords along the circle, 100 back.
    chord = 2 * 100 * np.sin(np.pi / 40)
    assert counts.tolist() == [20, 20]
    assert route.max() == pytest.approx(200 + 19 * chord, rel=1e-9)


def test_sweep_gives_each_machine_a_wedge_from_a_corner_depot():
    # A 12 x 12 grid with the depot at a corner (as pcb3038's): a giant tour cut into three
    # routes sends two of them across the others' areas empty; the sweep's sectors (each a
    # run of the order by angle) leave no such legs, and their min-max figure is lower.
    tasks = [Task(f"t{i}_{j}", 10.0 * (i + 1), 10.0 * j) for i in range(12) for j in range(12)]
    problem = Problem.build(
        [Machine(f"m{i}", 1.0, 1.0, 1.0, 0.0, 1.0, 1.0) for i in range(3)], tasks, (0.0, 0.0)
    )
    tables = CostTables.of(problem).kernel_args()
    n = len(tasks)
    nn = nearest_neighbours(problem.dist, 6)
    order = sweep_order(problem)
    longest = {}
    for name in ("giant tour", "sweep"):
        perm = np.arange(n, dtype=np.int64)
        counts = np.zeros(3, dtype=np.int64)
        args = (int(Objective.MINMAX), tables, nn, 1, NO_PINS(n), np.inf)
        if name == "sweep":
            sweep(make_state(1), perm, counts, order, *args, 50, np.inf)
            places = np.argsort(order)[perm]  # each task's place in the order by angle
            begin = 0
            for count in counts:
                assert sorted(places[begin : begin + count]) == list(range(begin, begin + count))
                begin += count
        else:
            giant_tour(make_state(1), perm, counts, *args, 50 * n, np.inf)
        assert_valid(perm, counts, n, 3, 1)
        longest[name] = route_lengths(perm, counts, tables).max()
    assert longest["sweep"] < 0.9 * longest["giant tour"]


def test_sweep_order_starts_after_the_widest_gap_and_needs_a_depot():
    # Tasks at 10, 20, 30 and 300 degrees around the depot: the widest gap is 30 -> 300.
    degrees = [20.0, 300.0, 10.0, 30.0]
    tasks = [
        Task(f"t{j}", np.cos(np.radians(d)), np.sin(np.radians(d))) for j, d in enumerate(degrees)
    ]
    machine = Machine("m", 1.0, 1.0, 1.0, 0.0, 1.0, 1.0)
    problem = Problem.build([machine], tasks, (0.0, 0.0))
    assert sweep_order(problem).tolist() == [1, 2, 0, 3]
    free = Problem(
        (machine,), tuple(tasks), problem.dist, problem.start_dist, problem.end_dist,
        problem.turns, problem.work_hours,
    )  # fmt: skip
    assert free.depot is None and sweep_order(free) is None


@SETTINGS
@given(chromosomes(), st.integers(0, 300), st.integers(2, 8))
def test_tour_ils_keeps_a_permutation_and_its_gain_is_the_true_shortening(case, kicks, k):
    state, perm, _ = case
    n = perm.size
    # Machine 1 starts and ends elsewhere than machine 0: the path is machine 1's.
    problem = problem_for(n, 2, 5 * n + k).starting_at([(100.0, 2900.0), (2900.0, 100.0)])
    tables = CostTables.of(problem).kernel_args()
    on_1 = np.array([0, n], dtype=np.int64)
    before = evaluate(perm, on_1, int(Objective.DISTANCE), tables, np.empty(2))
    nn = nearest_neighbours(problem.dist, k)
    gain = tour_ils(state, perm, 1, *tables[:3], nn, kicks, np.inf)
    assert sorted(perm.tolist()) == list(range(n))
    after = evaluate(perm, on_1, int(Objective.DISTANCE), tables, np.empty(2))
    assert gain >= 0.0
    assert before - after == pytest.approx(gain, rel=1e-9, abs=1e-6)


@SETTINGS
@given(chromosomes(), st.integers(0, 300), st.integers(2, 8), st.sampled_from(list(Objective)))
def test_route_ils_orders_one_route_again_and_its_gain_is_the_true_shortening(
    case, kicks, k, objective
):
    # One route's tasks in another order; the other routes as they were, every objective
    # no worse (each grows with a route's distance).
    state, perm, counts = case
    n, m = perm.size, counts.size
    problem = problem_for(n, m, 7 * n + k)
    tables = CostTables.of(problem).kernel_args()
    route = int(np.argmax(counts))
    begin, end = int(counts[:route].sum()), int(counts[: route + 1].sum())
    others = np.concatenate([perm[:begin], perm[end:]])
    before = route_lengths(perm, counts, tables)
    cost = evaluate(perm, counts, int(objective), tables, np.empty(m))
    gain = route_ils(
        state, perm, counts, route, tables, nearest_neighbours(problem.dist, k), NO_PINS(n),
        kicks, np.inf,
    )  # fmt: skip
    assert_valid(perm, counts, n, m)
    after = route_lengths(perm, counts, tables)
    assert np.array_equal(np.concatenate([perm[:begin], perm[end:]]), others)
    assert before[route] - after[route] == pytest.approx(gain, rel=1e-9, abs=1e-6)
    assert gain >= 0.0 and (gain == 0.0 or end - begin >= 8)
    assert evaluate(perm, counts, int(objective), tables, np.empty(m)) <= cost + 1e-6


def test_route_ils_leaves_a_route_whose_first_task_is_pinned():
    problem = problem_for(20, 2, 3)
    tables = CostTables.of(problem).kernel_args()
    perm = np.random.default_rng(1).permutation(20).astype(np.int64)
    counts = np.array([10, 10], dtype=np.int64)
    pins = NO_PINS(20)
    pins[perm[10]] = 1
    kept = perm.copy()
    nn = nearest_neighbours(problem.dist, 5)
    assert route_ils(make_state(1), perm, counts, 1, tables, nn, pins, 100, np.inf) == 0.0
    assert np.array_equal(perm, kept)
    assert route_ils(make_state(1), perm, counts, 0, tables, nn, pins, 100, np.inf) > 0.0


def test_a_large_instance_gets_a_smaller_population_never_below_the_floor():
    params = HybridParams()
    assert [params.population_for(n) for n in (51, 200, 760, 1002, 3038, 100_000)] == [
        200, 200, 200, 151, 50, 50,
    ]  # fmt: skip
    assert HybridParams(population=20).population_for(3038) == 20  # asked for fewer
    assert HybridParams(population_tasks=0).population_for(3038) == 200


def test_tour_ils_finds_the_optimal_tour_of_a_circle_and_repeats_itself():
    # Tasks on a circle, shuffled; the machine starts and ends at the centre: the best
    # path goes round the circle once. The same seed gives the same path.
    angles = np.linspace(0.0, 2 * np.pi, 60, endpoint=False)
    problem = Problem.build(
        [Machine("m", 1.0, 1.0, 1.0, 0.0, 1.0, 1.0)],
        [Task(f"t{j}", 100 * np.cos(a), 100 * np.sin(a)) for j, a in enumerate(angles)],
        (0.0, 0.0),
    )
    tables = CostTables.of(problem).kernel_args()
    nn = nearest_neighbours(problem.dist, 8)
    paths = []
    for _ in range(2):
        perm = np.random.default_rng(3).permutation(60).astype(np.int64)
        tour_ils(make_state(4), perm, 0, *tables[:3], nn, 5000, np.inf)
        paths.append(perm.tolist())
    route = np.empty(1)
    length = evaluate(np.array(paths[0]), np.array([60]), int(Objective.DISTANCE), tables, route)
    chord = 2 * 100 * np.sin(np.pi / 60)
    assert length == pytest.approx(200 + 59 * chord, rel=1e-9)
    assert paths[0] == paths[1]


@pytest.mark.parametrize(
    "bad",
    [
        {"ruin": -1},
        {"tour_kicks": -1},
        {"route_kicks": -1},
        {"population_tasks": -1},
        {"tour_share": 1.5},
        {"distance_share": -0.1},
        {"distance_slack": -0.1},
        {"restart": 1.5},
        {"squeeze": -1.0},
        {"squeeze": (0.002, float("nan"))},
        {"squeeze": (0.002, 1.5)},
        {"squeeze": 1.0},
        {"squeeze_exchange_road": -1.0},
        {"squeeze_exchange_road": float("nan")},
        {"squeeze_exchange_empty": 1.5},
        {"squeeze_exchange_empty": float("nan")},
    ],
)
def test_hybrid_params_refuse_a_bad_setting(bad):
    with pytest.raises(ValueError, match=next(iter(bad))):
        HybridParams(**bad)


def test_the_squeeze_takes_its_steps_in_turn_one_a_generation():
    default = HybridParams()
    loose = [-0.003] * 4  # the target above the makespan (strategic oscillation)
    in_turn = [default.squeeze_at(g) for g in range(1, 9)]
    assert in_turn == [0.002, 0.0002, *loose, 0.002, 0.0002]
    assert [HybridParams(squeeze=0.001).squeeze_at(g) for g in (1, 2, 3)] == [0.001] * 3
    for off in (0.0, ()):
        params = HybridParams(squeeze=off)
        assert params.squeeze_steps == () and params.squeeze_at(1) == 0.0
    # A step 0 is that generation's ILS of the min-max objective.
    assert HybridParams(squeeze=(0.0, 0.001)).squeeze_at(2) == 0.001


def test_solve_takes_the_squeeze_steps_in_turn_the_same_way_for_the_same_seed(monkeypatch):
    problem = problem_for(80, 8, 2)
    warm_up()  # its tiny solves run the ILS too
    steps = []
    elite_ils = planner.hybrid.ils_step

    def ils_step(*args):
        steps.append(args[-1])  # the squeeze's step, ils_step's last argument
        return elite_ils(*args)

    monkeypatch.setattr(planner.hybrid, "ils_step", ils_step)

    def routes(squeeze):
        params = HybridParams(squeeze=squeeze, ils_steps=10)
        return solve(problem, "makespan", "hybrid", stop_after(6), seed=3, params=params).routes

    in_turn = routes((0.002, 0.0002))
    assert steps == [0.002, 0.0002] * 3
    assert in_turn == routes((0.002, 0.0002))
    steps.clear()
    routes(0.001)
    assert steps == [0.001] * 6


def test_a_restart_keeps_the_best_found_before_and_repeats_for_the_same_seed():
    """``restart``: under a sum, a population whose elite has not improved for that share
    of the run starts again; the best found before is kept aside and returned unless
    beaten, so the history never worsens. Not under min-max, nor from a warm start."""
    problem = problem_for(30, 3, 4)
    params = HybridParams(population=10, ils_steps=2, restart=0.1)
    runs = [
        solve(problem, "distance", "hybrid", stop_after(80), seed=5, params=params) for _ in (0, 1)
    ]
    a, b = runs
    assert a.stats["restarts"] >= 1
    assert a.routes == b.routes and a.history == b.history
    assert sorted(j for r in a.routes for j in r) == list(range(30)) and all(a.routes)
    assert all(y <= x for x, y in zip(a.history, a.history[1:], strict=False))
    assert a.cost == pytest.approx(a.history[-1]) and a.cost == pytest.approx(min(a.history))
    assert a.cost == pytest.approx(a.figures.value(a.objective))
    never = [
        solve(problem, "minmax", "hybrid", stop_after(80), seed=5, params=params),
        solve(
            problem, "distance", "hybrid", stop_after(80), seed=5, params=params,
            initial_routes=a.routes,
        ),
    ]  # fmt: skip
    assert [r.stats["restarts"] for r in never] == [0.0, 0.0]


def test_a_deadline_gives_the_shortest_roads_among_plans_that_finish_within_it():
    """``finish_within_h``: once a plan finishes within the deadline the road distance
    decides, so a deadline above the strict makespan gives less road within it; one no
    plan meets leaves the search as it is without one (bit for bit)."""
    problem = problem_for(40, 4, 7)
    strict = solve(problem, "makespan", "hybrid", stop_after(30), seed=1)
    deadline = 1.1 * strict.figures.makespan_h
    within = solve(problem, "makespan", "hybrid", stop_after(30), seed=1, finish_within_h=deadline)
    assert within.figures.makespan_h <= deadline
    assert within.figures.distance_m < 0.97 * strict.figures.distance_m
    unmet = solve(problem, "makespan", "hybrid", stop_after(30), seed=1, finish_within_h=1e-3)
    assert unmet.routes == strict.routes and unmet.history == strict.history


def test_a_makespan_slack_trades_makespan_for_road_distance_in_the_answer():
    """With ``distance_share`` and ``distance_slack`` the answer is the plan of the last
    share, which may end up to the slack later for less road, not the best makespan seen
    before it (no restarts under the makespan, so no record kept aside)."""
    problem = problem_for(40, 4, 7)
    strict = solve(problem, "makespan", "hybrid", stop_after(30), seed=1)
    params = HybridParams(distance_share=0.5, distance_slack=0.05)
    slack = solve(problem, "makespan", "hybrid", stop_after(30), seed=1, params=params)
    assert slack.figures.distance_m < strict.figures.distance_m
    assert slack.figures.makespan_h > min(slack.history)  # it gave some makespan up
    assert slack.figures.makespan_h <= min(slack.history[:15]) * 1.05 + 1e-9
    assert slack.cost == pytest.approx(slack.history[-1], rel=1e-5)
