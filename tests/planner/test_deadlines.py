"""Time limits hold whatever the geometry: a field too many working widths across is refused
at once; coverage and local search look at the deadline, so a pathological input returns or
fails clearly (naming the field) within the limit plus a second."""

import math
import time

import numpy as np
import pytest
from shapely.geometry import Polygon

from planner.cost import CostTables, Objective
from planner.coverage import MAX_SWATHS, cover_field, rectangle_field
from planner.errors import Deadline, GeometryError, PlannerError, TimeLimitError
from planner.farm import Farm, Field
from planner.field_plan import plan_farm
from planner.geo import LocalFrame
from planner.local_search import improve_allocation, nearest_neighbours, optimal_split
from planner.problem import Machine, Problem, Task
from planner.solve import stop_after, warm_up

SLACK_S = 1.0  # what the brief allows beyond the limit
# A benchmark may share the machine: the bound is the limit plus the slack, measured with
# time.monotonic around the whole call (nothing else is timed).

NARROW = Machine("mm", 0.001, 100.0, 10.0, 0.003, 2.5, 5.0)
TRACTOR = Machine("t", 3.0, 5000.0, 10.0, 0.003, 2.5, 5.0)
TURNING = Machine("r", 3.0, 5000.0, 10.0, 0.003, 2.5, 5.0, min_turn_radius_m=5.0)


def farm_of(*fields: tuple[str, Polygon]) -> Farm:
    return Farm(
        fields=tuple(Field(fid, fid, poly, poly) for fid, poly in fields),
        garage=(-50.0, -50.0),
        garage_lonlat=(87.3, 44.0),
        frame=LocalFrame.around(87.3, 44.0),
    )


def timed(call):  # type: ignore[no-untyped-def]
    """(result or the PlannerError raised, seconds)."""
    started = time.monotonic()
    try:
        out = call()
    except PlannerError as exc:
        out = exc
    return out, time.monotonic() - started


@pytest.fixture(scope="module", autouse=True)
def _compiled() -> None:
    warm_up()  # numba's compilation is never charged to a time limit


# ----------------------------------------------------------------------------- up front


def test_a_millimetre_width_is_refused_at_once_naming_field_width_and_count():
    farm = farm_of(("Hof-Nord 12", rectangle_field(300.0, 300.0)))
    out, took = timed(lambda: plan_farm(farm, [NARROW], stop=stop_after(None, 2.0)))
    assert isinstance(out, GeometryError)
    assert took < 1.0  # up front: nothing was laid out
    message = str(out)
    assert "'Hof-Nord 12'" in message
    assert "0.001 m" in message and "300,000 swaths" in message
    assert f"{MAX_SWATHS:,}" in message and "'mm'" in message


def test_the_cap_counts_across_the_narrowest_or_the_given_direction():
    # 20 m x 80 m at 0.002 m: 10,000 widths across at the narrowest; at 90 deg, 40,000.
    long_field = rectangle_field(20.0, 80.0)
    with pytest.raises(GeometryError, match=r"'f'.*80\.0 m across its swath direction"):
        cover_field(long_field, 0.002, field_id="f", angle_deg=90.0)
    with pytest.raises(GeometryError, match=r"20\.0 m across at its narrowest.*10,051 swaths"):
        cover_field(long_field, 0.00199, field_id="f")
    # Exactly at the cap it is not refused up front: the deadline is what stops it.
    with pytest.raises(TimeLimitError, match="'f'"):
        cover_field(long_field, 0.002, field_id="f", deadline=Deadline(0.2))


def test_the_cap_never_refuses_a_real_field():
    # Slanted 2 km x 3 km at 0.5 m (the narrowest implement a scenario accepts): 4,000.
    poly = rectangle_field(2000.0, 3000.0, 33.0)
    cov = cover_field(poly, 60.0, field_id="big but real")
    assert len(cov.swaths) == math.ceil(2000.0 / 60.0)
    with pytest.raises(TimeLimitError):  # past the cap check, into the layout
        cover_field(poly, 0.5, field_id="big but real", deadline=Deadline(0.05))


# ----------------------------------------------------------------------------- deadlines


@pytest.mark.parametrize("machine", [TRACTOR, TURNING], ids=["hops", "turns"])
def test_a_20_km_field_returns_or_fails_within_the_limit(machine):
    limit = 1.0
    farm = farm_of(("Steppe", rectangle_field(20_000.0, 20_000.0)))
    out, took = timed(lambda: plan_farm(farm, [machine], stop=stop_after(None, limit)))
    assert took < limit + SLACK_S, f"{took:.2f} s"
    if isinstance(out, PlannerError):
        assert isinstance(out, TimeLimitError)
        message = str(out)
        assert "'Steppe'" in message and f"{limit:g} s" in message
        assert "6,667 swaths across" in message and f"{machine.id!r}" in message
    else:  # a fast machine: a plan, made in time
        assert out.machines[0].field_ids == ["Steppe"]


def test_coverage_stops_within_a_short_limit_at_any_stage():
    # Each stage looks at the clock; whichever runs when the limit passes raises.
    poly = rectangle_field(20_000.0, 20_000.0)
    for limit in (0.05, 0.3, 1.0):
        out, took = timed(
            lambda limit=limit: cover_field(
                poly, 3.0, field_id="Steppe", turn_radius_m=5.0, deadline=Deadline(limit)
            )
        )
        assert isinstance(out, TimeLimitError), out
        assert took < limit + SLACK_S
        assert str(out).startswith("field 'Steppe': coverage at a working width of 3 m")


def test_a_jagged_outline_returns_or_fails_within_the_limit():
    # 4,000 vertices, every other one 30 m in: thousands of reflex corners and cells.
    k = np.arange(4000)
    angle = 2 * np.pi * k / len(k)
    radius = np.where(k % 2 == 0, 1500.0, 1470.0)
    poly = Polygon(np.column_stack([radius * np.cos(angle), radius * np.sin(angle)]))
    assert poly.is_valid
    limit = 1.0
    farm = farm_of(("Zackenfeld", poly))
    out, took = timed(lambda: plan_farm(farm, [TURNING], stop=stop_after(None, limit)))
    assert took < limit + SLACK_S, f"{took:.2f} s"
    if isinstance(out, PlannerError):
        assert isinstance(out, TimeLimitError) and "'Zackenfeld'" in str(out)


def test_a_normal_farm_plans_in_its_limit_with_time_for_the_solver():
    fields = [(f"f{k}", rectangle_field(60.0, 100.0, 0.0, (150.0 * k, 0.0))) for k in range(6)]
    farm = farm_of(*fields)
    limit = 1.0
    out, took = timed(
        lambda: plan_farm(farm, [TRACTOR, TURNING], "makespan", stop=stop_after(None, limit))
    )
    assert not isinstance(out, PlannerError), out
    assert limit <= took < limit + SLACK_S  # the solver used the time it had
    assert sorted(f for m in out.machines for f in m.field_ids) == sorted(f for f, _ in fields)
    assert out.solver.elapsed_s < limit  # coverage's share came out of the solver's


def test_without_a_time_limit_nothing_is_cut_short():
    farm = farm_of(("f", rectangle_field(60.0, 100.0)))
    plan = plan_farm(farm, [TRACTOR], stop=stop_after(5))
    assert plan.solver.generations == 5


# ----------------------------------------------------------------------------- solver


def big_problem(n: int, m: int = 4) -> Problem:
    rng = np.random.default_rng(1)
    machines = [Machine(f"t{i}", 6.9, 7000.0, 10.0, 0.004, 3.0, 7.0) for i in range(m)]
    xy = rng.uniform(0.0, 20_000.0, (n, 2))
    tasks = [Task(f"f{j}", float(x), float(y), 9000.0, 120.0, 75.0) for j, (x, y) in enumerate(xy)]
    return Problem.build(machines, tasks, (0.0, 0.0), name="big")


def test_the_solver_keeps_its_limit_on_a_huge_instance():
    # 2,500 tasks: one generation's local search alone took over a second before.
    from planner.solve import solve

    problem = big_problem(2500)
    limit = 0.5
    out, took = timed(lambda: solve(problem, "makespan", "ighoa", stop_after(None, limit), seed=1))
    assert took < limit + SLACK_S, f"{took:.2f} s"
    flat = sorted(j for route in out.routes for j in route)
    assert flat == list(range(problem.num_tasks))


def test_local_search_stops_at_a_past_deadline_with_a_valid_chromosome():
    problem = big_problem(300)
    tables = CostTables.of(problem).kernel_args()
    n, m = problem.num_tasks, problem.num_machines
    pins = np.full(n, -1, dtype=np.int64)
    nn = nearest_neighbours(problem.dist, 10)
    perm = np.random.default_rng(2).permutation(n).astype(np.int64)
    counts = np.full(m, n // m, dtype=np.int64)
    counts[-1] += n - counts.sum()
    before = perm.copy(), counts.copy()
    past = time.monotonic() - 1.0
    obj = int(Objective.MAKESPAN)
    assert improve_allocation(perm, counts, obj, tables, nn, 1, 50, pins, past) == 0
    assert np.array_equal(perm, before[0]) and np.array_equal(counts, before[1])
    assert optimal_split(perm, counts, obj, tables, 1, pins, past) == math.inf
    assert np.array_equal(counts, before[1])
    # Without one (or one far off) the same kernels work as before.
    assert improve_allocation(perm, counts, obj, tables, nn, 1, 50, pins, math.inf) > 0
    assert sorted(perm.tolist()) == list(range(n)) and counts.sum() == n
