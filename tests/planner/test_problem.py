"""Construction-time checks name the bad value."""

import math

import numpy as np
import pytest

from planner.errors import ProblemError
from planner.problem import Machine, Problem, Task


def machine(ident="m1", **kw):
    args = dict(
        working_width_m=5.0,
        capacity_m2h=5000.0,
        road_speed_kmh=10.0,
        turn_time_h=0.003,
        road_fuel_lh=2.5,
        work_fuel_lh=5.0,
    )
    args.update(kw)
    return Machine(ident, **args)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("working_width_m", 0.0, "working_width_m must be positive, not 0.0"),
        ("working_width_m", -3.0, "must be positive"),
        ("road_speed_kmh", 0.0, "road_speed_kmh must be positive"),
        ("capacity_m2h", math.nan, "capacity_m2h must be a finite number"),
        ("turn_time_h", -1.0, "turn_time_h must not be negative"),
    ],
)
def test_bad_machine_values_are_named(field, value, message):
    with pytest.raises(ProblemError, match=message) as err:
        machine("tractor-9", **{field: value})
    assert "tractor-9" in str(err.value)


def test_nan_coordinates_named():
    with pytest.raises(ProblemError, match="task 'f3': x must be a finite number"):
        Task("f3", math.nan, 0.0)


def test_duplicate_ids_no_tasks_no_machines():
    tasks = [Task("a", 0.0, 1.0), Task("b", 1.0, 0.0)]
    with pytest.raises(ProblemError, match="duplicate machine id 'm1'"):
        Problem.build([machine(), machine()], tasks, (0.0, 0.0))
    with pytest.raises(ProblemError, match="duplicate task id 'a'"):
        Problem.build([machine()], [tasks[0], tasks[0]], (0.0, 0.0))
    with pytest.raises(ProblemError, match="no tasks"):
        Problem.build([machine()], [], (0.0, 0.0))
    with pytest.raises(ProblemError, match="no machines"):
        Problem.build([], tasks, (0.0, 0.0))
    with pytest.raises(ProblemError, match="3 machines need at least one task each"):
        Problem.build([machine("x"), machine("y"), machine("z")], tasks, (0.0, 0.0))


def test_arrays_are_read_only_and_checked():
    tasks = [Task("a", 0.0, 1.0), Task("b", 1.0, 0.0)]
    problem = Problem.build([machine()], tasks, (0.0, 0.0))
    with pytest.raises(ValueError):
        problem.dist[0, 1] = 5.0
    bad = np.array([[0.0, -1.0], [1.0, 0.0]])
    with pytest.raises(ProblemError, match="dist has a negative entry"):
        Problem.build([machine()], tasks, (0.0, 0.0), dist=bad)
