"""Formulas (1)-(6) against cases computed by hand, and the compiled evaluation against a
slow pure-Python recomputation."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.cost import (
    TIE_BREAK,
    CostTables,
    Objective,
    evaluate,
    figures,
    fleet_gain,
    fleet_value,
    largest_three,
    split_routes,
)
from planner.errors import ProblemError
from planner.problem import Machine, Problem, Task, rectangle_turns


def paper_machine(ident: str = "am1") -> Machine:
    # Table 6, machine 1: 6.9 m, 7000 m2/h, 10 km/h, 7 L/h working, 3 L/h road, 0.004 h/turn.
    return Machine(ident, 6.9, 7000.0, 10.0, 0.004, 3.0, 7.0)


def test_rectangle_turns_formula():
    # The paper's n_turn: a U-turn a swath (tests/planner/test_paper.py: its Tables 8, 10).
    # 127 m across at 6.9 m: ceil(18.4) = 19 swaths.
    assert rectangle_turns(127.0, 6.9) == 19
    assert rectangle_turns(69.0, 6.9) == 10  # exactly 10 swaths
    assert rectangle_turns(5.0, 6.9) == 1
    assert rectangle_turns(0.0, 6.9) == 0  # a TSPLIB city


def test_formulas_one_to_six_by_hand():
    # Garage at the origin; task A at (300, 400) (500 m away), task B at (300, 0).
    tasks = [
        Task("A", 300.0, 400.0, area_m2=8890.0, width_m=127.0, length_m=70.0),
        Task("B", 300.0, 0.0, area_m2=7000.0, width_m=69.0, length_m=101.0),
    ]
    problem = Problem.build([paper_machine()], tasks, (0.0, 0.0))
    figs = figures(problem, [[0, 1]])
    route = figs.routes[0]
    # (1)-(2): 500 (garage->A) + 400 (A->B) + 300 (B->garage).
    assert route.distance_m == pytest.approx(1200.0)
    drive_h = 1200.0 / 10_000.0  # 10 km/h
    turns = 19 + 10  # the paper's n_turn: ceil(127 / 6.9) and 69 / 6.9 swaths
    work_h = 8890.0 / 7000.0 + 7000.0 / 7000.0
    # (6): travel + turning + working time.
    assert route.time_h == pytest.approx(drive_h + turns * 0.004 + work_h)
    # (5): travel and turns at the road rate, work at the working rate.
    assert route.fuel_l == pytest.approx(drive_h * 3.0 + turns * 0.004 * 3.0 + work_h * 7.0)
    assert route.turns == turns
    assert figs.value(Objective.DISTANCE) == pytest.approx(1200.0)
    assert figs.value(Objective.MAKESPAN) == pytest.approx(route.time_h)


def test_objectives_sum_and_max():
    tasks = [Task(str(k), float(10 * k), 0.0) for k in range(1, 4)]
    machines = [paper_machine("a"), paper_machine("b")]
    problem = Problem.build(machines, tasks, (0.0, 0.0))
    figs = figures(problem, [[0], [1, 2]])
    assert figs.distance_m == pytest.approx(20.0 + 60.0)
    assert figs.max_distance_m == pytest.approx(60.0)
    assert figs.value(Objective.MINMAX) == pytest.approx(60.0)
    assert figs.makespan_h == pytest.approx(max(r.time_h for r in figs.routes))
    assert figs.time_h == pytest.approx(sum(r.time_h for r in figs.routes))


def test_objective_names():
    assert Objective.parse("minsum") is Objective.DISTANCE
    assert Objective.parse("minmax") is Objective.MINMAX
    assert Objective.parse("makespan") is Objective.MAKESPAN
    with pytest.raises(ValueError, match="unknown objective 'fastest'"):
        Objective.parse("fastest")


@st.composite
def problems_and_chromosomes(draw):
    n = draw(st.integers(2, 9))
    m = draw(st.integers(1, min(n, 4)))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    machines = [
        Machine(
            f"m{i}",
            float(rng.uniform(2, 8)),
            float(rng.uniform(3000, 8000)),
            float(rng.uniform(5, 20)),
            float(rng.uniform(0, 0.01)),
            float(rng.uniform(1, 4)),
            float(rng.uniform(4, 9)),
        )
        for i in range(m)
    ]
    tasks = [
        Task(
            f"t{j}",
            float(rng.uniform(0, 2000)),
            float(rng.uniform(0, 2000)),
            float(rng.uniform(1000, 20000)),
            float(rng.uniform(20, 200)),
            float(rng.uniform(20, 200)),
        )
        for j in range(n)
    ]
    problem = Problem.build(machines, tasks, (float(rng.uniform(0, 2000)), 0.0))
    perm = rng.permutation(n)
    cuts = np.sort(rng.choice(np.arange(1, n), size=m - 1, replace=False))
    counts = np.diff(np.concatenate(([0], cuts, [n])))
    return problem, perm.astype(np.int64), counts.astype(np.int64)


def slow_value(problem, routes, objective):
    """Formulas (1)-(6) in plain Python, without any shared helper."""
    per_route = []
    for i, route in enumerate(routes):
        mc = problem.machines[i]
        pts = [problem.depot] + [(problem.tasks[j].x, problem.tasks[j].y) for j in route]
        pts.append(problem.depot)
        s = sum(math.dist(a, b) for a, b in zip(pts, pts[1:], strict=False)) if route else 0.0
        turns = sum(rectangle_turns(problem.tasks[j].width_m, mc.working_width_m) for j in route)
        work = sum(problem.tasks[j].area_m2 / mc.capacity_m2h for j in route)
        drive = s / (mc.road_speed_kmh * 1000)
        t = drive + turns * mc.turn_time_h + work
        c = (
            drive * mc.road_fuel_lh
            + turns * mc.turn_time_h * mc.road_fuel_lh
            + work * mc.work_fuel_lh
        )
        per_route.append((s, t, c))
    s_all = [r[0] for r in per_route]
    return {
        Objective.DISTANCE: sum(s_all),
        Objective.TIME: sum(r[1] for r in per_route),
        Objective.FUEL: sum(r[2] for r in per_route),
        Objective.MAKESPAN: max(r[1] for r in per_route),
        Objective.MINMAX: max(s_all),
    }[objective]


@settings(max_examples=60, deadline=None, derandomize=True)
@given(problems_and_chromosomes(), st.sampled_from(list(Objective)))
def test_compiled_cost_equals_slow_recomputation(case, objective):
    problem, perm, counts = case
    tables = CostTables.of(problem).kernel_args()
    route_cost = np.empty(problem.num_machines)
    value = evaluate(perm, counts, int(objective), tables, route_cost)
    routes = split_routes(perm, counts)
    expected = slow_value(problem, routes, objective)
    tie = 0.0
    if objective in (Objective.MAKESPAN, Objective.MINMAX):
        tie = 1e-9 * sum(r.distance_m for r in figures(problem, routes).routes)
    assert value == pytest.approx(expected + tie, rel=1e-9, abs=1e-9)
    assert figures(problem, routes).value(objective) == pytest.approx(expected, rel=1e-9)


@st.composite
def replanned_problems(draw):
    """A random problem re-planned: machines at random points now, busy for random hours,
    ending at the garage; some machines may stay idle (min_tasks_per_machine = 0)."""
    problem, perm, counts = draw(problems_and_chromosomes())
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    m = problem.num_machines
    starts = [
        None if rng.random() < 0.2 else (float(rng.uniform(0, 2000)), float(rng.uniform(0, 2000)))
        for _ in range(m)
    ]
    ready = [0.0 if rng.random() < 0.3 else float(rng.uniform(0, 5)) for _ in range(m)]
    problem = dataclasses.replace(problem, min_tasks_per_machine=0).starting_at(
        starts, ready_h=ready
    )
    if m > 1 and rng.random() < 0.5:  # an idle machine, possibly a busy one
        counts = counts.copy()
        idle = int(rng.integers(m))
        counts[(idle + 1) % m] += counts[idle]
        counts[idle] = 0
    return problem, perm, counts, starts, ready


def slow_replanned_value(problem, routes, objective, starts, ready):
    """Formulas (1)-(6) in plain Python from each machine's own start, plus its ready
    time for the time figures when it has a task; an idle machine costs nothing."""
    per_route = []
    for i, route in enumerate(routes):
        mc = problem.machines[i]
        if not route:
            per_route.append((0.0, 0.0, 0.0))
            continue
        start = starts[i] if starts[i] is not None else problem.depot
        pts = [start] + [(problem.tasks[j].x, problem.tasks[j].y) for j in route]
        pts.append(problem.depot)
        s = sum(math.dist(a, b) for a, b in zip(pts, pts[1:], strict=False))
        turns = sum(rectangle_turns(problem.tasks[j].width_m, mc.working_width_m) for j in route)
        work = sum(problem.tasks[j].area_m2 / mc.capacity_m2h for j in route)
        drive = s / (mc.road_speed_kmh * 1000)
        t = ready[i] + drive + turns * mc.turn_time_h + work
        c = (
            drive * mc.road_fuel_lh
            + turns * mc.turn_time_h * mc.road_fuel_lh
            + work * mc.work_fuel_lh
        )
        per_route.append((s, t, c))
    s_all = [r[0] for r in per_route]
    return {
        Objective.DISTANCE: sum(s_all),
        Objective.TIME: sum(r[1] for r in per_route),
        Objective.FUEL: sum(r[2] for r in per_route),
        Objective.MAKESPAN: max(r[1] for r in per_route),
        Objective.MINMAX: max(s_all),
    }[objective]


@settings(max_examples=80, deadline=None, derandomize=True)
@given(replanned_problems(), st.sampled_from(list(Objective)))
def test_costs_from_starts_and_ready_times_equal_slow_recomputation(case, objective):
    problem, perm, counts, starts, ready = case
    tables = CostTables.of(problem).kernel_args()
    route_cost = np.empty(problem.num_machines)
    value = evaluate(perm, counts, int(objective), tables, route_cost)
    routes = split_routes(perm, counts)
    expected = slow_replanned_value(problem, routes, objective, starts, ready)
    tie = 0.0
    if objective in (Objective.MAKESPAN, Objective.MINMAX):
        tie = 1e-9 * sum(r.distance_m for r in figures(problem, routes).routes)
    assert value == pytest.approx(expected + tie, rel=1e-9, abs=1e-9)
    assert figures(problem, routes).value(objective) == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_idle_busy_machine_does_not_set_the_makespan():
    tasks = [Task("A", 300.0, 400.0, 7000.0, 60.0, 70.0)]
    machines = [paper_machine("a"), paper_machine("b")]
    problem = Problem.build(machines, tasks, (0.0, 0.0), min_tasks_per_machine=0).starting_at(
        [None, (300.0, 400.0)], ready_h=[0.0, 9.0]
    )
    idle_b = figures(problem, [[0], []])
    assert idle_b.routes[1].time_h == 0.0 and idle_b.routes[1].distance_m == 0.0
    assert idle_b.makespan_h == idle_b.routes[0].time_h < 9.0
    busy_b = figures(problem, [[], [0]])
    # b is on the field already (0 m there), 500 m home, and busy 9 h first.
    assert busy_b.routes[1].distance_m == pytest.approx(500.0)
    assert busy_b.makespan_h == pytest.approx(9.0 + 0.05 + 9 * 0.004 + 1.0)  # ceil(60/6.9)


def test_starting_at_with_a_distance_function_and_bad_input():
    tasks = [Task("A", 300.0, 400.0), Task("B", 0.0, 100.0)]
    problem = Problem.build([paper_machine()], tasks, (0.0, 0.0))
    moved = problem.starting_at([(1.0, 2.0)], distance=lambda p, t: 10.0 * p[0] + t.y)
    np.testing.assert_allclose(moved.start_dist, [[410.0, 110.0]])
    np.testing.assert_allclose(moved.end_dist, problem.end_dist)
    with pytest.raises(ProblemError, match="2 start positions given for 1 machines"):
        problem.starting_at([None, None])
    with pytest.raises(ProblemError, match="ready_h must not be negative"):
        problem.starting_at([None], ready_h=[-1.0])
    with pytest.raises(ProblemError, match="start x must be a finite number"):
        problem.starting_at([(math.nan, 0.0)])


def test_a_min_max_figure_counts_as_at_least_the_cap():
    values, lengths = np.array([3.0, 5.0]), np.array([100.0, 200.0])
    alike = np.ones(2)
    for objective in (3, 4):
        plain = fleet_value(objective, values, lengths, 0.0, alike)
        assert plain == pytest.approx(5.0 + TIE_BREAK * 300.0)
        assert fleet_value(objective, values, lengths, 4.0, alike) == plain  # below the figure
        assert fleet_value(objective, values, lengths, 7.0, alike) == pytest.approx(plain + 2.0)
    assert fleet_value(0, values, lengths, 7.0, alike) == 8.0  # the sums have no cap


@given(
    st.integers(1, 7), st.integers(0, 2**31), st.sampled_from([0, 1, 2, 3, 4]),
    st.sampled_from([0.0, 5.0, -5.0, -8.0]), st.booleans(), st.booleans(),
)  # fmt: skip
@settings(max_examples=300, deadline=None)
def test_fleet_gain_is_what_fleet_value_falls_by(m, seed, objective, cap, two, tied):
    """The local search's O(1) price of a move (one route changed, or two) is the fall of
    the fleet's figure recomputed over every route: under the sums, the min-max figures
    (with and without a cap; the longest route among those changed, or tied) and the
    squeeze (cap < 0)."""
    rng = np.random.default_rng(seed)
    values, lengths = rng.uniform(0.0, 10.0, m), rng.uniform(0.0, 1e4, m)
    if tied:
        values[rng.integers(m)] = values.max()
    weights = rng.uniform(0.0, 3.0, m)
    top = np.empty(3, dtype=np.int64)
    largest_three(values, top)
    assert values[top[0]] == values.max()
    assert sorted(values[top[top >= 0]], reverse=True) == sorted(values, reverse=True)[:3]
    a = int(rng.integers(m))
    b = int(rng.integers(m)) if two and m > 1 else -1
    b = -1 if b == a else b
    value_a, length_a, value_b, length_b = rng.uniform(0.0, 12.0, 4) * [1.0, 1e3, 1.0, 1e3]
    after_values, after_lengths = values.copy(), lengths.copy()
    after_values[a], after_lengths[a] = value_a, length_a
    if b >= 0:
        after_values[b], after_lengths[b] = value_b, length_b
    fall = fleet_value(objective, values, lengths, cap, weights) - fleet_value(
        objective, after_values, after_lengths, cap, weights
    )
    gain = fleet_gain(
        objective, values, lengths, cap, weights, top, a, value_a, length_a, b, value_b, length_b
    )
    assert gain == pytest.approx(fall, rel=1e-9, abs=1e-9)
