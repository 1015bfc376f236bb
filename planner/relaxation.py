"""The linear relaxation of assigning tasks to machines under the makespan (unrelated
machines, R||Cmax): minimise C such that every task is shared out among the machines
(x_ij >= 0, sum_i x_ij = 1) and every machine's hours, ready_i + sum_j c_ij x_ij, are at
most C, where c_ij is the hours machine i spends on task j: its service alone, or with its
share of the travel no route avoids (:func:`unavoidable_hours`).

Its optimal duals are weights lambda on the machines (lambda >= 0, summing to one) that
say what an hour of each machine is worth to the makespan: any plan's makespan is at
least the lambda-weighted mean of its machines' hours, and that mean is at least
sum_i lambda_i ready_i + sum_j min_i lambda_i c_ij, whatever the plan (the bound). A fast
machine's hour is worth more than a slow one's: its weight is higher.

- :func:`machine_weights`: the duals. :func:`hour_weights` makes them the weights of the
  machines' hours in the squeeze (:func:`planner.cost.squeeze_figure`), so that a plan
  with fewer *weighted* hours is one the makespan can come down from: an hour saved on a
  fast machine is worth more than one on a slow machine, as the makespan sees it.
  The hours are :func:`unavoidable_hours`: from the service alone, the duals would count
  driving on every machine alike, and weighed so they were 0.15 % worse than all alike at
  100 x 10, where driving is a larger share (benchmarks/RESULTS.md, 2026-11-26 22:30).
- :func:`weighted_bound`: the bound from any weights, evaluated in numpy (valid whatever
  the LP solver's tolerance); ``benchmarks/suite/farm.py``'s bounds LB (the service
  alone) and LBt (:func:`unavoidable_hours`).

Solved by HiGHS' interior point method (:func:`scipy.optimize.linprog`) on a sparse
matrix: 0.13 s at 500 tasks x 30 machines, 1.3 s at 2 000 x 50.
"""

from __future__ import annotations

import math
import time

import numpy as np

from planner.cost import CostTables
from planner.errors import PlannerError, ProblemError
from planner.problem import FloatArray

# The largest relaxation solved for the squeeze's weights, in tasks x machines (1.3 s at
# 2 000 x 50); beyond it the machines' hours count alike.
MAX_VARIABLES = 100_000
# The share of the time left to the deadline that the relaxation may take.
TIME_SHARE = 0.1


def hour_weights(tables: CostTables, deadline: float = math.inf) -> FloatArray:
    """What an hour of each machine counts in the squeeze: the relaxation's duals for the
    tables' :func:`unavoidable_hours` and pins, times the number of machines (so that all
    alike is all 1). All 1 when the relaxation has more than :data:`MAX_VARIABLES`
    variables, or is not solved within :data:`TIME_SHARE` of the time to ``deadline``
    (:func:`time.perf_counter`).

    Busy machines' ready times are left out: a machine without a task does not wait for
    its ready time in a plan, but would in the relaxation, and one busy past the others'
    end would take all the weight (the overload of the squeeze sees the ready times)."""
    m, n = tables.task_hours.shape
    alike = np.ones(m)
    if m < 2 or m * n > MAX_VARIABLES:
        return alike
    weights = machine_weights(
        unavoidable_hours(tables),
        pinned=tables.pinned_machine,
        time_limit=TIME_SHARE * (deadline - time.perf_counter()),
    )
    return alike if weights is None else m * weights


def unavoidable_hours(tables: CostTables) -> FloatArray:
    """[machine, task]: the hours machine i spends on task j, service and its share of the
    travel no route avoids: half the two shortest legs into and out of the task
    (:func:`incident_legs_m`) at the machine's road speed. A machine's route takes at
    least the sum of these over its tasks (the proof: ``benchmarks/suite/farm.py``)."""
    legs = incident_legs_m(tables.dist, tables.start_dist, tables.end_dist)
    return tables.task_hours + legs * tables.road_hours_per_m[:, None]


def incident_legs_m(dist: FloatArray, start_dist: FloatArray, end_dist: FloatArray) -> FloatArray:
    """[machine, task]: half the two shortest legs that can lead into and out of the task
    on that machine's route (metres): the two smallest of the task's distances to the
    other tasks and to the machine's start and end (each its own node)."""
    n = dist.shape[0]
    others = np.array(dist, dtype=np.float64)
    np.fill_diagonal(others, np.inf)
    two = np.partition(others, 1, axis=1)[:, :2] if n > 1 else np.full((n, 1), np.inf)
    legs = np.empty(start_dist.shape)
    for i in range(start_dist.shape[0]):
        ends = np.column_stack([two, start_dist[i], end_dist[i]])
        legs[i] = np.partition(ends, 1, axis=1)[:, :2].sum(axis=1) / 2.0
    return legs


def machine_weights(
    costs: np.ndarray,
    ready: np.ndarray | None = None,
    pinned: np.ndarray | None = None,
    time_limit: float = math.inf,
) -> FloatArray | None:
    """The relaxation's optimal duals, [machine], summing to one; None if not solved
    within ``time_limit`` seconds. ``costs`` [machine, task] are hours; ``ready``
    [machine] the hours a machine is busy before it starts (0 if None); ``pinned`` [task]
    the machine a task must stay with, or -1 (none if None)."""
    m, n = costs.shape
    if m == 0 or n == 0:
        return np.full(m, 1.0 / max(m, 1))
    if not np.isfinite(costs).all() or (costs < 0).any():
        raise ProblemError("the relaxation's costs must be finite hours >= 0")
    if not time_limit > 0.0:
        return None
    # Here, not at the top: only the makespan needs it, and it takes 0.2 s to load.
    from scipy.optimize import linprog
    from scipy.sparse import coo_array

    ready = np.zeros(m) if ready is None else np.asarray(ready, dtype=np.float64)
    # Variables: x_ij at i * n + j, then C at m * n.
    columns = np.arange(m * n)
    machine_of = columns // n
    task_of = columns % n
    share = coo_array((np.ones(m * n), (task_of, columns)), shape=(n, m * n + 1))  # sum_i x_ij
    load = coo_array(
        (
            np.concatenate([costs.ravel(), -np.ones(m)]),
            (
                np.concatenate([machine_of, np.arange(m)]),
                np.concatenate([columns, np.full(m, m * n)]),
            ),
        ),
        shape=(m, m * n + 1),
    )  # ready_i + sum_j c_ij x_ij - C <= 0
    upper = np.ones(m * n + 1)
    upper[-1] = np.inf
    if pinned is not None:
        pin = np.asarray(pinned)[task_of]
        upper[:-1][(pin >= 0) & (pin != machine_of)] = 0.0  # a pinned task stays put
    objective = np.zeros(m * n + 1)
    objective[-1] = 1.0
    result = linprog(
        objective,
        A_ub=load.tocsr(),
        b_ub=-ready,
        A_eq=share.tocsr(),
        b_eq=np.ones(n),
        bounds=np.column_stack([np.zeros(m * n + 1), upper]),
        method="highs-ipm",
        options={"time_limit": time_limit} if math.isfinite(time_limit) else None,
    )
    if result.status == 1:  # out of time
        return None
    if result.status != 0:
        raise PlannerError(f"the assignment relaxation has no optimum: {result.message}")
    weights = np.abs(np.asarray(result.ineqlin.marginals, dtype=np.float64))
    total = weights.sum()
    return weights / total if total > 0 else np.full(m, 1.0 / m)


def weighted_bound(
    costs: np.ndarray, weights: np.ndarray, ready: np.ndarray | None = None
) -> float:
    """sum_i lambda_i ready_i + sum_j min_i lambda_i costs[i, j] for ``weights`` lambda
    (>= 0, summing to one): a lower bound on the makespan of any assignment of the tasks
    with these costs (see the module)."""
    lam = np.asarray(weights, dtype=np.float64)
    lam = lam / lam.sum()
    start = 0.0 if ready is None else float(lam @ np.asarray(ready, dtype=np.float64))
    return start + float((lam[:, None] * costs).min(axis=0).sum())
