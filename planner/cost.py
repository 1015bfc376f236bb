"""The paper's cost model, formulas (1)-(6), compiled for the solvers and readable for reports.

For machine i driving route r (its tasks in order):

    s_i = D(start_i, r_1) + sum_k D(r_k, r_k+1) + D(r_last, end_i)                  (1), (2)
    c_i = s_i / v_i * c_vi + sum_j n_turn(i,j) * t_T(i) * c_vi + sum_j S_j / w_i * c_wi  (5)
    t_i = s_i / v_i + sum_j n_turn(i,j) * t_T(i) + sum_j S_j / w_i                       (6)

with s in metres and v in km/h (so s / v is s / (1000 v) hours); formula (5) is
:func:`planner.formulas.fuel_l`, shared with the plan's figures and the review. A machine busy for
``ready_h[i]`` hours before it can start (a re-plan) has that added to t_i when its route
has a task; a machine with no task costs nothing (it is not part of the plan), so it never
sets the makespan. Its fuel is not charged: that work is done whatever the plan. The in-field parts
depend only on which machine works which task, so they are precomputed per
[machine, task] in :class:`CostTables`; a route's time and fuel then follow from its
distance. Objectives: ``distance`` = sum s_i (formula 3), ``time`` = sum t_i,
``fuel`` = sum c_i, ``makespan`` = max t_i, ``minmax`` = max s_i.

A chromosome is the paper's two-part encoding (§4.1): ``perm`` is the task order and
``counts[i]`` the number of consecutive tasks of ``perm`` that machine i takes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from planner import formulas
from planner.choices import Objective
from planner.problem import FloatArray, Problem

# Weight of the tie-breaker (total distance, metres) added to the min-max objectives:
# small enough never to trade a real gain in the primary figure for distance.
TIE_BREAK = 1e-9
# Under the squeeze (a makespan target, squeeze_figure), what an hour of a route over the
# target weighs against an hour of the fleet's (weighted) total: 10 and 100 found the same makespans
# at 500 x 30, 1 none better than the plan it started from (benchmarks/RESULTS.md,
# 2026-11-26).
OVERLOAD = 10.0


@dataclass(frozen=True)
class CostTables:
    """The arrays the kernels read, derived once from a :class:`Problem`."""

    dist: FloatArray  # [task, task] metres
    start_dist: FloatArray  # [machine, task]
    end_dist: FloatArray  # [machine, task]
    road_hours_per_m: FloatArray  # [machine] 1 / (1000 v_i)
    road_fuel_lh: FloatArray  # [machine] c_vi
    task_hours: FloatArray  # [machine, task] n_turn * t_T + S / w
    task_fuel: FloatArray  # [machine, task] n_turn * t_T * c_v + S / w * c_w
    ready_h: FloatArray  # [machine] hours busy before the route starts (time objectives)
    pinned_machine: np.ndarray  # [task] int64, the machine a task stays first with, or -1
    # [machine] what an hour of the machine counts in the squeeze (squeeze_figure): all 1,
    # or the machines' worth to the makespan (planner.relaxation.hour_weights), set by solve
    hour_weights: FloatArray

    @classmethod
    def of(cls, problem: Problem) -> CostTables:
        turn_h = problem.machine_array("turn_time_h")
        road_fuel = problem.machine_array("road_fuel_lh")
        work_fuel = problem.machine_array("work_fuel_lh")
        turn_hours = problem.turns * turn_h[:, None]
        task_hours = turn_hours + problem.work_hours
        task_fuel = formulas.fuel_l(
            0.0, turn_hours, problem.work_hours, road_fuel[:, None], work_fuel[:, None]
        )
        return cls(
            dist=np.ascontiguousarray(problem.dist),
            start_dist=np.ascontiguousarray(problem.start_dist),
            end_dist=np.ascontiguousarray(problem.end_dist),
            road_hours_per_m=1.0 / (1000.0 * problem.machine_array("road_speed_kmh")),
            road_fuel_lh=road_fuel,
            task_hours=task_hours,
            task_fuel=task_fuel,
            ready_h=np.ascontiguousarray(problem.ready_h, dtype=np.float64),
            pinned_machine=np.ascontiguousarray(problem.pinned_machine, dtype=np.int64),
            hour_weights=np.ones(problem.num_machines),
        )

    def kernel_args(self) -> tuple[FloatArray, ...]:
        """What every kernel takes as ``tables`` (the pins are passed on their own)."""
        return (
            self.dist,
            self.start_dist,
            self.end_dist,
            self.road_hours_per_m,
            self.road_fuel_lh,
            self.task_hours,
            self.task_fuel,
            self.ready_h,
            self.hour_weights,
        )


@njit(cache=True, nogil=True)
def route_distance(perm, begin, count, machine, dist, start_dist, end_dist):  # type: ignore[no-untyped-def]
    """Formula (1) for the ``count`` tasks of ``perm`` from ``begin`` done by ``machine``."""
    if count == 0:
        return 0.0
    prev = perm[begin]
    s = start_dist[machine, prev]
    for k in range(begin + 1, begin + count):
        cur = perm[k]
        s += dist[prev, cur]
        prev = cur
    return s + end_dist[machine, prev]


@njit(cache=True, nogil=True)
def evaluate(perm, counts, objective, tables, route_cost):  # type: ignore[no-untyped-def]
    """The objective value of one chromosome; fills ``route_cost[i]`` with machine i's share.

    ``tables`` is :meth:`CostTables.kernel_args`. A route's share is the figure the
    objective adds up or maximises: s_i for distance and minmax, t_i for time and makespan,
    c_i for fuel (the "path cost" of §4.3's overshoot).
    """
    dist, start_dist, end_dist, road_hours_per_m, road_fuel_lh, task_hours, task_fuel, ready, _ = (
        tables
    )
    m = counts.shape[0]
    total = 0.0
    worst = 0.0
    total_s = 0.0
    begin = 0
    for i in range(m):
        cnt = counts[i]
        s = route_distance(perm, begin, cnt, i, dist, start_dist, end_dist)
        total_s += s
        if objective == 0 or objective == 4:
            value = s
        else:
            drive_h = s * road_hours_per_m[i]
            if objective == 2:
                value = drive_h * road_fuel_lh[i]
                for k in range(begin, begin + cnt):
                    value += task_fuel[i, perm[k]]
            else:
                value = drive_h
                if cnt > 0:
                    value += ready[i]
                for k in range(begin, begin + cnt):
                    value += task_hours[i, perm[k]]
        route_cost[i] = value
        total += value
        if value > worst:
            worst = value
        begin += cnt
    if objective == 3 or objective == 4:
        return worst + TIE_BREAK * total_s
    return total


@njit(cache=True, nogil=True)
def evaluate_population(perms, counts, objective, tables, costs, route_costs):  # type: ignore[no-untyped-def]
    """Evaluate every row of a population in place."""
    for p in range(perms.shape[0]):
        costs[p] = evaluate(perms[p], counts[p], objective, tables, route_costs[p])


@njit(cache=True, nogil=True)
def route_value(objective, machine, s, extra, road_h, road_f, ready, size):  # type: ignore[no-untyped-def]
    """A route's share of the objective (as :func:`evaluate` gives it) from its distance
    ``s`` and ``extra``, the sum of its tasks' in-field figures (hours, or litres for
    fuel); ``size`` is its number of tasks (an empty route costs nothing, a busy
    machine's ready time included). For the local search's O(1) move evaluations. (The
    machine's figures read first, then the sum picked, as :func:`planner.operators.leg`
    does, for its speed.)"""
    return _route_value_of(
        objective, s, extra, road_h[machine], road_f[machine], ready[machine], size
    )


@njit(cache=True, nogil=True)
def _route_value_of(objective, s, extra, road_h, road_f, ready, size):  # type: ignore[no-untyped-def]
    """:func:`route_value` from the machine's own figures."""
    if objective == 0 or objective == 4:
        return s
    if objective == 2:
        return s * road_h * road_f + extra
    if size == 0:
        return s * road_h + extra
    return s * road_h + extra + ready


@njit(cache=True, nogil=True)
def fleet_value(objective, values, lengths, cap, weights):  # type: ignore[no-untyped-def]
    """The objective from every route's share (``values``) and distance (``lengths``).
    ``cap`` > 0: a min-max figure is taken as at least ``cap``, so that below the cap only
    the tie-breaker, the total distance, counts. ``cap`` < 0: the squeeze towards the
    target ``-cap`` with the machines' hour ``weights`` (:func:`squeeze_figure`), plus the
    tie-breaker. 0: the objective.

    It never falls when a route's share and distance grow (the weights are never
    negative): :func:`planner.moves.recreate` takes a route's cheapest place as its best."""
    if cap < 0.0:
        return squeeze_figure(values, -cap, weights) + TIE_BREAK * lengths.sum()
    if objective == 3 or objective == 4:
        return max(values.max(), cap) + TIE_BREAK * lengths.sum()
    return values.sum()


@njit(cache=True, nogil=True)
def squeeze_figure(values, target, weights):  # type: ignore[no-untyped-def]
    """The makespan as a sum (the squeeze, :func:`planner.hybrid.ils_step`): every
    route's share (``values``, hours) times its machine's weight (``weights``:
    :attr:`CostTables.hour_weights`) added up, and each hour a route ends after
    ``target`` counted :data:`OVERLOAD` times more. Below the target the fleet's weighted
    hours decide, so a field moves to the machine that does it in fewer of them, or to a
    shorter road, whichever route it leaves; above it the overloads do."""
    total = 0.0
    for i in range(values.shape[0]):
        total += squeeze_term(values[i], target, weights[i])
    return total


@njit(cache=True, nogil=True)
def squeeze_term(hours, target, weight):  # type: ignore[no-untyped-def]
    """One route's term of :func:`squeeze_figure`: its ``hours`` times its machine's
    ``weight``, and each hour after ``target`` :data:`OVERLOAD` times more."""
    return weight * hours + OVERLOAD * max(0.0, hours - target)


@njit(cache=True, nogil=True)
def largest_three(values, top):  # type: ignore[no-untyped-def]
    """The routes of the three largest ``values`` into ``top``, largest first (-1 where
    there are fewer routes): what :func:`fleet_gain` needs to price a change of a min-max
    figure in O(1)."""
    top[:] = -1
    for r in range(values.shape[0]):
        v = values[r]
        if top[0] < 0 or v > values[top[0]]:
            top[2], top[1], top[0] = top[1], top[0], r
        elif top[1] < 0 or v > values[top[1]]:
            top[2], top[1] = top[1], r
        elif top[2] < 0 or v > values[top[2]]:
            top[2] = r


@njit(cache=True, nogil=True)
def fleet_gain(  # type: ignore[no-untyped-def]
    objective, values, lengths, cap, weights, top, a, value_a, length_a, b, value_b, length_b
):
    """How much :func:`fleet_value` falls when route ``a``'s share and distance become
    ``value_a`` and ``length_a`` and route ``b``'s (``b`` >= 0, another route; -1: none)
    ``value_b`` and ``length_b``, in O(1) (``top``: :func:`largest_three` of ``values`` as
    they are): the moves' price in the local search, without adding up every route. The
    figures are read first and the gain worked out from the numbers (as
    :func:`planner.operators.leg` does)."""
    at_b = max(b, 0)
    return _gain_of(
        objective, cap, a, values[a], lengths[a], weights[a], value_a, length_a,
        b, values[at_b], lengths[at_b], weights[at_b], value_b, length_b,
        top[0], values[max(top[0], 0)], top[1], values[max(top[1], 0)],
        top[2], values[max(top[2], 0)],
    )  # fmt: skip


@njit(cache=True, nogil=True)
def _gain_of(  # type: ignore[no-untyped-def]
    objective, cap, a, old_a, old_length_a, weight_a, value_a, length_a,
    b, old_b, old_length_b, weight_b, value_b, length_b, r0, v0, r1, v1, r2, v2,
):  # fmt: skip
    """:func:`fleet_gain` from the routes' figures read."""
    tie = old_length_a - length_a
    if b >= 0:
        tie += old_length_b - length_b
    if cap < 0.0:  # the squeeze: fleet_value is a sum of squeeze_terms
        target = -cap
        gain = squeeze_term(old_a, target, weight_a) - squeeze_term(value_a, target, weight_a)
        if b >= 0:
            gain += squeeze_term(old_b, target, weight_b)
            gain -= squeeze_term(value_b, target, weight_b)
        return gain + TIE_BREAK * tie
    if objective == 3 or objective == 4:
        # The largest share of the routes that stay as they are: the first of the three
        # largest that is neither a nor b.
        rest = -np.inf
        if r0 >= 0 and r0 != a and r0 != b:
            rest = v0
        elif r1 >= 0 and r1 != a and r1 != b:
            rest = v1
        elif r2 >= 0 and r2 != a and r2 != b:
            rest = v2
        new = max(max(rest, value_a), cap)
        if b >= 0:
            new = max(new, value_b)
        return max(v0, cap) - new + TIE_BREAK * tie
    gain = old_a - value_a
    if b >= 0:
        gain += old_b - value_b
    return gain


@dataclass(frozen=True)
class RouteFigures:
    """Every figure of one machine's route."""

    machine_id: str
    tasks: tuple[str, ...]
    distance_m: float  # s_i
    fuel_l: float  # c_i
    time_h: float  # t_i
    turns: int  # sum of n_turn(i, j) over its tasks


@dataclass(frozen=True)
class Figures:
    """All figures of a solution: per machine and for the fleet."""

    routes: tuple[RouteFigures, ...]

    @property
    def distance_m(self) -> float:
        return sum(r.distance_m for r in self.routes)

    @property
    def fuel_l(self) -> float:
        return sum(r.fuel_l for r in self.routes)

    @property
    def time_h(self) -> float:
        return sum(r.time_h for r in self.routes)

    @property
    def makespan_h(self) -> float:
        return max(r.time_h for r in self.routes)

    @property
    def max_distance_m(self) -> float:
        return max(r.distance_m for r in self.routes)

    def value(self, objective: Objective) -> float:
        """The objective's own figure (without tie-breaker)."""
        return {
            Objective.DISTANCE: self.distance_m,
            Objective.TIME: self.time_h,
            Objective.FUEL: self.fuel_l,
            Objective.MAKESPAN: self.makespan_h,
            Objective.MINMAX: self.max_distance_m,
        }[objective]

    def as_dict(self) -> dict[str, object]:
        return {
            "distance_m": self.distance_m,
            "fuel_l": self.fuel_l,
            "time_h": self.time_h,
            "makespan_h": self.makespan_h,
            "max_distance_m": self.max_distance_m,
            "machines": [
                {
                    "id": r.machine_id,
                    "tasks": list(r.tasks),
                    "distance_m": r.distance_m,
                    "fuel_l": r.fuel_l,
                    "time_h": r.time_h,
                    "turns": r.turns,
                }
                for r in self.routes
            ],
        }


def figures(problem: Problem, routes: list[list[int]] | tuple[tuple[int, ...], ...]) -> Figures:
    """Formulas (1)-(6) for routes given as task indices per machine (plain Python)."""
    tables = CostTables.of(problem)
    out = []
    for i, route in enumerate(routes):
        s = 0.0
        if route:
            s = float(tables.start_dist[i, route[0]] + tables.end_dist[i, route[-1]])
            s += sum(float(tables.dist[a, b]) for a, b in zip(route, route[1:], strict=False))
        drive_h = s * float(tables.road_hours_per_m[i])
        out.append(
            RouteFigures(
                machine_id=problem.machines[i].id,
                tasks=tuple(problem.tasks[j].id for j in route),
                distance_m=s,
                fuel_l=drive_h * float(tables.road_fuel_lh[i])
                + sum(float(tables.task_fuel[i, j]) for j in route),
                time_h=drive_h
                + sum(float(tables.task_hours[i, j]) for j in route)
                + (float(tables.ready_h[i]) if route else 0.0),
                turns=int(sum(problem.turns[i, j] for j in route)),
            )
        )
    return Figures(routes=tuple(out))


def split_routes(perm: np.ndarray, counts: np.ndarray) -> list[list[int]]:
    """The two-part chromosome as one list of task indices per machine."""
    routes, begin = [], 0
    for cnt in counts:
        routes.append([int(j) for j in perm[begin : begin + int(cnt)]])
        begin += int(cnt)
    return routes
