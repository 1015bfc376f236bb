"""Planning with real field geometry: coverage per machine, allocation, start corners.

1. Every field is covered (:mod:`planner.coverage`) once for each distinct working width
   and turning radius of the fleet; the U-turns of the machine that works a field replace
   formula (5)'s rectangle estimate, its hours stay S / w.
2. The solver (:func:`planner.solve.solve`) allocates and orders the fields. Its distance
   between two fields is the length of the transit (:class:`planner.roads.TransitNetwork`)
   from the centroid of one to the centroid of the other (a point inside the field when the
   centroid is not): inside the field to its best gate, along the roads, from the other
   field's gate to its centroid; without roads, around the other fields. Likewise from the
   garage. Formula (2)'s straight line between centroids is what ``network=None`` gives.
3. A post-optimisation picks each field's start corner along every route exactly, by
   dynamic programming over the four corners: the transit runs from the exit of one field
   to the entry of the next, and from and back to the garage, along the roads (or around the
   fields); its points are kept in :attr:`Visit.approach` and :attr:`MachinePlan.return_path`.
The solver prices the turns as the figures below do (:func:`field_work`). The figures of
the result (distance, fuel, time, turns) are those of the driven geometry:
road metres are the transit lengths plus the in-field driving between cells; when the
coverage plans drivable turns (:meth:`FieldCoverage.turn_length_m` > 0) a field's turns take
their length at the working speed, at the road fuel rate (formula (5)'s charge for turns),
otherwise the paper's t_T per turn (formula (6)).

A time limit in the stop criterion (:class:`planner.solve.MaxRuntime`) holds for the whole
of :func:`plan_farm`, from its call: coverage looks at it in its loops and raises
:class:`~planner.errors.TimeLimitError` naming the field once it has passed (there is no
plan without every field's coverage); the solver gets what is left and returns its best
by then (:class:`planner.solve.UntilDeadline`).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from planner import formulas
from planner.cost import CostTables, Objective, figures, route_distance, route_value
from planner.coverage import XY, FieldCoverage, Swath, cover_field
from planner.errors import NO_DEADLINE, Deadline, GeometryError, TimeLimitError
from planner.farm import Farm, Field
from planner.problem import Machine, Problem, Task
from planner.roads import TransitNetwork
from planner.solve import AnyOf, Criterion, GenerationCallback, Result, solve

log = logging.getLogger(__name__)

CORNERS = 4
FloatArray = NDArray[np.float64]

SOLVER_MIN_SHARE = 0.2
"""The least share of a plan's time limit the solver searches for: where the coverage used
more than the rest, the plan ends that much past the limit (:func:`plan_farm`)."""

UNABLE_H = 1e6
"""The hours a machine is taken to spend on a field it cannot work (narrower than its
implement: :func:`cover_farm`): no plan that gives it one is kept under the objectives that
count hours or litres (makespan, time, fuel), and :func:`settle_unable` moves such a field
to a machine that can under the others, which count only the road."""


class FarmCoverage(dict[tuple[str, str], FieldCoverage]):
    """Coverage keyed (machine id, field id) for the pairs where the machine can work the
    field; ``unable`` says why for the others (a mixed fleet: a 12 m sprayer does not fit
    a 6 m strip that the 3 m mower does)."""

    def __init__(self) -> None:
        super().__init__()
        self.unable: dict[tuple[str, str], str] = {}

    def merged(self, newer: FarmCoverage) -> FarmCoverage:
        """This coverage with ``newer``'s added (its pairs win)."""
        out = FarmCoverage()
        for part in (self, newer):
            out.update(part)
            out.unable.update(part.unable)
        return out


@dataclass(frozen=True)
class Visit:
    """One field worked by one machine, started at ``corner``."""

    field: Field
    coverage: FieldCoverage
    corner: int
    # Transit from where the machine was (garage or the previous field's exit) to this
    # field's entry: the points in between, along roads or around other fields.
    approach: tuple[XY, ...] = ()
    # A re-plan's visit of the rest of a field in progress (planner.replan): the share of
    # the field's work left, and for each of this visit's segments (swaths, then headland
    # ring edges, as laid out for a mission) its index among the segments of the field's
    # first planned visit (through every re-plan since), so a segment keeps its number.
    work_share: float = 1.0
    original_segments: tuple[int, ...] = ()

    @property
    def entry(self) -> XY:
        return self.coverage.entry(self.corner)

    @property
    def exit(self) -> XY:
        return self.coverage.exit(self.corner)

    @property
    def swaths(self) -> tuple[Swath, ...]:
        return self.coverage.path(self.corner)

    @property
    def headland(self) -> tuple[tuple[XY, ...], ...]:
        return self.coverage.headland_path(self.corner)

    @property
    def links(self) -> tuple[tuple[XY, ...], ...]:
        """For the move from swath k to k + 1, the points that keep it inside the field."""
        return self.coverage.link(self.corner)


@dataclass(frozen=True)
class MachinePlan:
    """One machine's route and its figures, by formulas (1), (5), (6) on the geometry."""

    machine: Machine
    visits: tuple[Visit, ...]
    road_m: float  # garage -> entries/exits -> garage, plus driving between cells in fields
    work_h: float  # sum of S_j / w_i
    turns: int
    time_h: float
    fuel_l: float
    # Transit from the last field's exit back to the garage: the points in between.
    return_path: tuple[XY, ...] = ()
    ready_h: float = 0.0  # busy before the route starts (a re-plan), included in time_h

    @property
    def field_ids(self) -> list[str]:
        return [v.field.id for v in self.visits]


@dataclass(frozen=True)
class FarmPlan:
    farm: Farm
    machines: tuple[MachinePlan, ...]
    objective: Objective
    solver: Result
    # What the plan was made from, kept so that a re-plan need not compute it again: every
    # field's coverage per machine (as cover_farm keys it) and the transit network.
    coverage: FarmCoverage = field(default_factory=FarmCoverage, repr=False, compare=False)
    network: TransitNetwork | None = field(default=None, repr=False, compare=False)

    @property
    def distance_m(self) -> float:
        return sum(m.road_m for m in self.machines)

    @property
    def fuel_l(self) -> float:
        return sum(m.fuel_l for m in self.machines)

    @property
    def time_h(self) -> float:
        return sum(m.time_h for m in self.machines)

    @property
    def makespan_h(self) -> float:
        return max(m.time_h for m in self.machines)


def cover_farm(
    farm: Farm,
    machines: Sequence[Machine],
    known: FarmCoverage | None = None,
    deadline: Deadline = NO_DEADLINE,
    every_field: bool = True,
) -> FarmCoverage:
    """Coverage of every field for every machine that can work it, keyed (machine id,
    field id); computed once per distinct working width and turning radius, and not at all
    when ``known`` (an earlier result for the same farm) has it. A field a machine cannot
    work (:func:`planner.coverage.cover_field` refuses it for its width: too narrow) is
    left to the others, with a warning, and the reason in :attr:`FarmCoverage.unable`;
    one that no machine can work raises the first machine's
    :class:`~planner.errors.GeometryError`, naming the farm, machine and field (without
    ``every_field``, it is in ``unable`` for every machine: a re-plan leaves it). Raises
    :class:`~planner.errors.TimeLimitError` naming the field once ``deadline`` passes."""
    by_width: dict[tuple[float, float], dict[str, FieldCoverage | GeometryError]] = {}
    out = FarmCoverage()
    known = known or FarmCoverage()
    for machine in machines:
        width = machine.working_width_m
        key = (width, machine.min_turn_radius_m)
        pairs = [(machine.id, f.id) for f in farm.fields]
        if all(pair in known or pair in known.unable for pair in pairs):
            out.update({pair: known[pair] for pair in pairs if pair in known})
            out.unable.update({pair: known.unable[pair] for pair in pairs if pair not in known})
            continue
        if key not in by_width:
            by_width[key] = {}
            for f in farm.fields:
                try:
                    by_width[key][f.id] = cover_field(
                        f.boundary,
                        width,
                        quiet=True,  # its notes said for the machines planned to use it
                        field_id=f.id,
                        angle_deg=None
                        if f.work_angle_deg is None
                        else farm.grid_angle_deg(f.id, f.work_angle_deg),
                        headland_passes=f.headland_passes,
                        turn_radius_m=machine.min_turn_radius_m,
                        deadline=deadline,
                    )
                except TimeLimitError as exc:
                    raise TimeLimitError(
                        f"{farm.source}: machine {machine.id!r} ({width:g} m wide): {exc}"
                    ) from exc
                except GeometryError as exc:
                    by_width[key][f.id] = exc
        for f in farm.fields:
            cov = by_width[key][f.id]
            if isinstance(cov, GeometryError):
                out.unable[(machine.id, f.id)] = (
                    f"{farm.source}: machine {machine.id!r} ({width:g} m wide): {cov}"
                )
            else:
                out[(machine.id, f.id)] = cov
    for f in farm.fields:
        reasons = [out.unable.get((m.id, f.id)) for m in machines]
        if machines and all(reasons) and every_field:
            others = ", ".join(repr(m.id) for m in machines[1:])
            raise GeometryError(
                f"{reasons[0]}"
                + (f"; no machine of the fleet can work it (nor {others})" if others else "")
            )
        fresh = [  # said once, not again at each re-plan
            m for m in machines if (m.id, f.id) in out.unable and (m.id, f.id) not in known.unable
        ]
        if fresh and not all(reasons):
            able = [m.id for m in machines if (m.id, f.id) in out]
            log.warning(
                "%s%s; the field is left to %s, %s",
                out.unable[(fresh[0].id, f.id)],
                f" (and {', '.join(m.id for m in fresh[1:])} cannot either)" if fresh[1:] else "",
                ", ".join(able),
                "the machines that can work it" if len(able) > 1 else "the one that can work it",
            )
    return out


def say_notes(coverage: FarmCoverage, planned: Sequence[tuple[str, str]]) -> None:
    """Warn of what the coverages of the ``planned`` (machine id, field id) pairs leave to
    be said (:attr:`~planner.coverage.FieldCoverage.notes`), each once, naming the machines:
    not of the coverages no machine is given (another width of the fleet's)."""
    by_note: dict[str, list[str]] = {}  # the machine ids a note is said for
    for pair in planned:
        for note in coverage[pair].notes:
            by_note.setdefault(note, []).append(pair[0])
    for note, ids in by_note.items():
        log.warning("%s (%s)", note, ", ".join(f"machine {m!r}" for m in dict.fromkeys(ids)))


def settle_unable(result: Result, coverage: FarmCoverage) -> Result:
    """``result`` with no machine keeping a field it cannot work (:data:`UNABLE_H` hours
    in its problem), with a warning; ``result`` itself when there is none. The objectives
    of road alone (distance, min-max) do not see which machine can work a field; the
    others see it, and leave one there only when stopped very early. The better, for the
    objective, of two ways: the routes handed round the machines as they stand, so that
    none keeps a field it cannot work (:func:`_handed_round`: the search laid out good
    routes for the wrong machines); and each such field moved to the machine, and the
    place in its route, where it costs the objective least (after a pinned first field)."""
    problem = result.problem
    unable = problem.work_hours >= UNABLE_H
    wrong = [(i, j) for i, route in enumerate(result.routes) for j in route if unable[i, j]]
    if not wrong:
        return result
    tables = CostTables.of(problem)
    obj = result.objective
    moved, moves = _moved(problem, tables, obj, unable, result.routes, wrong)
    options = [moved]
    handed = _handed_round(problem, tables, obj, unable, result.routes)
    if handed is not None:
        options.append(handed)
    best = min(options, key=lambda routes: _figure(problem, obj, routes))
    for was, j, to in moves if best is moved else [(i, j, -1) for i, j in wrong]:
        machine, field_id = problem.machines[was].id, problem.tasks[j].id
        log.warning(
            "%s; the search gave it to that machine (%s), so %s",
            coverage.unable.get(
                (machine, field_id), f"machine {machine!r} cannot work {field_id!r}"
            ),
            f"the objective {obj.name.lower()} counts only the road"
            if obj in (Objective.DISTANCE, Objective.MINMAX)
            else "stopped early",
            f"it goes to {problem.machines[to].id}"
            if to >= 0
            else "the routes are handed round the machines",
        )
    settled = tuple(tuple(route) for route in best)
    return dataclasses.replace(result, routes=settled, figures=figures(problem, settled))


def fewest_hours_among_equals(result: Result) -> Result:
    """Under the road alone (distance, min-max) with every machine leaving from and going
    back to the same place, a route's road is the same whichever machine drives it, so the
    machines tie: the routes handed round so that they take the fewest hours in all (an
    assignment problem), where the objective's figure stays as it is; ``result`` itself
    otherwise. (The first machine of a tie took a field: a 6.9 m machine with 1.35 h where
    a 6 m one that hops needs 0.29 h; an outside review.)"""
    from scipy.optimize import linear_sum_assignment

    obj, problem = result.objective, result.problem
    if obj not in (Objective.DISTANCE, Objective.MINMAX) or len(result.routes) < 2:
        return result
    tables = CostTables.of(problem)
    if not (
        np.allclose(tables.start_dist, tables.start_dist[:1])
        and np.allclose(tables.end_dist, tables.end_dist[:1])
    ):
        return result  # (machines starting where they stand: a re-plan's)
    m = len(result.routes)
    unable = problem.work_hours >= UNABLE_H
    hours = _route_costs(problem, tables, Objective.TIME, unable, result.routes)
    finite = np.isfinite(hours)
    rows, cols = linear_sum_assignment(np.where(finite, hours, 1e12))
    if not finite[rows, cols].all():
        return result
    handed: list[tuple[int, ...]] = [() for _ in range(m)]
    for r, k in zip(rows.tolist(), cols.tolist(), strict=True):
        handed[k] = tuple(result.routes[r])
    was, now = _figure(problem, obj, result.routes)[0], _figure(problem, obj, handed)[0]
    before = sum(hours[r, r] for r in range(m) if np.isfinite(hours[r, r]))
    if now > was * (1.0 + 1e-9) or hours[rows, cols].sum() >= before - 1e-9:
        return result
    return dataclasses.replace(
        result, routes=tuple(handed), figures=figures(problem, tuple(handed))
    )


def _figure(
    problem: Problem, obj: Objective, routes: Sequence[Sequence[int]]
) -> tuple[float, float]:
    """The objective's figure of ``routes``, then their road metres."""
    found = figures(problem, [list(route) for route in routes])
    return found.value(obj), found.distance_m


def _metres(tables: CostTables, k: int, route: Sequence[int]) -> float:
    """Machine k's road metres along ``route`` (formula (1))."""
    perm = np.asarray(route, dtype=np.int64)
    return float(
        route_distance(perm, 0, len(route), k, tables.dist, tables.start_dist, tables.end_dist)
    )


def _share(
    tables: CostTables, obj: Objective, k: int, route: Sequence[int], metres: float
) -> float:
    """Machine k's share of the objective for ``route`` of ``metres``, as the solver
    counts it (:func:`planner.cost.route_value`)."""
    in_field = tables.task_fuel if obj is Objective.FUEL else tables.task_hours
    extra = float(sum(in_field[k, t] for t in route))
    return float(
        route_value(
            int(obj),
            k,
            metres,
            extra,
            tables.road_hours_per_m,
            tables.road_fuel_lh,
            tables.ready_h,
            len(route),
        )
    )


def _moved(
    problem: Problem,
    tables: CostTables,
    obj: Objective,
    unable: NDArray[np.bool_],
    given: Sequence[Sequence[int]],
    wrong: Sequence[tuple[int, int]],
) -> tuple[list[list[int]], list[tuple[int, int, int]]]:
    """``given`` with each (machine, task) of ``wrong`` moved in turn to where it costs the
    objective least among the machines that can work it (under a sum the least it adds,
    under min-max and the makespan the least longest route; then the least road); and the
    moves (from, task, to)."""
    routes = [list(route) for route in given]
    for i, j in wrong:
        routes[i].remove(j)
    moves = []
    for was, j in wrong:
        best: tuple[tuple[float, float], int, int] | None = None
        lengths = [_metres(tables, k, route) for k, route in enumerate(routes)]
        shares = [_share(tables, obj, k, r, lengths[k]) for k, r in enumerate(routes)]
        for k, route in enumerate(routes):
            if unable[k, j]:
                continue
            others = max((v for q, v in enumerate(shares) if q != k), default=0.0)
            first = 1 if route and problem.pinned_machine[route[0]] == k else 0
            for at in range(first, len(route) + 1):
                added = _inserted_m(tables, k, route, at, j)
                share = _share(tables, obj, k, [*route, j], lengths[k] + added)
                if obj in (Objective.MINMAX, Objective.MAKESPAN):
                    key = (max(share, others), added)
                else:
                    key = (share - shares[k], added)
                if best is None or key < best[0]:
                    best = (key, k, at)
        assert best is not None  # cover_farm leaves no field without a machine that can
        _, k, at = best
        routes[k].insert(at, j)
        moves.append((was, j, k))
    return routes, moves


def _handed_round(
    problem: Problem,
    tables: CostTables,
    obj: Objective,
    unable: NDArray[np.bool_],
    given: Sequence[Sequence[int]],
) -> list[list[int]] | None:
    """The routes of ``given``, each whole, handed to the machines so that none has a field
    it cannot work (a route with a pinned field stays with its machine) at the least cost:
    under a sum the least total of the routes' figures on their new machines, under min-max
    and the makespan the least longest, then the least total (an assignment problem,
    :func:`scipy.optimize.linear_sum_assignment`); None if there is no such way."""
    from scipy.optimize import linear_sum_assignment

    m = len(given)
    cost = _route_costs(problem, tables, obj, unable, given)
    finite = np.isfinite(cost)
    big = 1.0 + 2.0 * m * float(np.abs(cost[finite]).max(initial=1.0))
    if obj in (Objective.MINMAX, Objective.MAKESPAN):
        # The least bottleneck: the least threshold under which an assignment exists.
        levels = np.unique(cost[finite])
        if not len(levels):
            return None
        lo, hi = 0, len(levels) - 1
        while lo < hi:
            mid = (lo + hi) // 2
            under = np.where(cost <= levels[mid], 0.0, 1.0)
            rows, cols = linear_sum_assignment(under)
            if under[rows, cols].sum() == 0.0:
                hi = mid
            else:
                lo = mid + 1
        finite &= cost <= levels[lo]
    rows, cols = linear_sum_assignment(np.where(finite, cost, big))
    if not finite[rows, cols].all():
        return None
    out: list[list[int]] = [[] for _ in range(m)]
    for r, k in zip(rows.tolist(), cols.tolist(), strict=True):
        out[k] = list(given[r])
    return out


def _route_costs(
    problem: Problem,
    tables: CostTables,
    obj: Objective,
    unable: NDArray[np.bool_],
    routes: Sequence[Sequence[int]],
) -> FloatArray:
    """[route, machine]: each whole route's share of ``obj`` on each machine; infinite on
    one that cannot work a field of it, or for a route with a field pinned to another."""
    m = len(routes)
    cost = np.full((m, m), np.inf)
    for r, route in enumerate(routes):
        pinned = any(problem.pinned_machine[t] == r for t in route)
        for k in range(m):
            if not (any(unable[k, t] for t in route) or (pinned and k != r)):
                cost[r, k] = _share(tables, obj, k, route, _metres(tables, k, route))
    return cost


def _inserted_m(tables: CostTables, k: int, route: Sequence[int], at: int, j: int) -> float:
    """The metres machine k's route grows by with task j put at position ``at``."""
    if not route:
        return float(tables.start_dist[k, j] + tables.end_dist[k, j])
    before = tables.start_dist[k, j] if at == 0 else tables.dist[route[at - 1], j]
    after = tables.end_dist[k, j] if at == len(route) else tables.dist[j, route[at]]
    if at == 0:
        was = tables.start_dist[k, route[0]]
    elif at == len(route):
        was = tables.end_dist[k, route[-1]]
    else:
        was = tables.dist[route[at - 1], route[at]]
    return float(before + after - was)


def farm_problem(
    farm: Farm,
    machines: Sequence[Machine],
    coverage: FarmCoverage,
    network: TransitNetwork | None = None,
    objective: Objective = Objective.MAKESPAN,
) -> Problem:
    """The solver's view of the farm: centroids, areas, real turn counts per machine, and
    with ``network`` the transit lengths between centroids (else straight lines). Under
    ``objective`` a sum, every machine works a field when there are enough (the paper's
    assumption 2: else the sum is least with the fleet in the garage); under the makespan
    or min-max a machine that would only delay the work stays in the garage."""
    tasks = []
    for f in farm.fields:
        c = f.boundary.centroid
        rect = f.boundary.minimum_rotated_rectangle
        xs, ys = rect.exterior.coords.xy
        sides = sorted(float(np.hypot(xs[k + 1] - xs[k], ys[k + 1] - ys[k])) for k in range(2))
        tasks.append(Task(f.id, float(c.x), float(c.y), f.area_m2, sides[0], sides[1]))
    turns, work_hours = field_work(farm, machines, coverage)
    # The paper has every machine work (its assumption 2: more tasks than machines); with
    # more machines than fields, or machines too wide for some fields, the spare ones
    # simply stay in the garage. A bottleneck objective needs no such rule: it uses every
    # machine that brings the end nearer, and forced, a slow one set the makespan (a
    # 0.4 ha/h robot took 5.28 h where the others were done in 1.22 h).
    sums = objective not in (Objective.MAKESPAN, Objective.MINMAX)
    min_tasks = 1 if sums and len(tasks) >= len(machines) and not coverage.unable else 0
    dist = depot_dist = None
    if network is not None:
        points = [farm.garage] + [field_anchor(f) for f in farm.fields]
        lengths = network.length_matrix(points, [None] + [f.id for f in farm.fields])
        dist, depot_dist = lengths[1:, 1:], lengths[0, 1:]
    return Problem.build(
        machines,
        tasks,
        farm.garage,
        dist=dist,
        depot_dist=depot_dist,
        turns=turns,
        work_hours=work_hours,
        min_tasks_per_machine=min_tasks,
        name="farm",
    )


def field_work(
    farm: Farm, machines: Sequence[Machine], coverage: FarmCoverage
) -> tuple[FloatArray, FloatArray]:
    """The solver's turns and work hours per (machine, field), priced as
    :func:`machine_figures` does. Where the coverage plans the turns, their hours (mean over
    the four start corners, which the solver does not choose) enter as U-turn equivalents,
    hours / t_T, so that formulas (5)-(6) charge them at the road fuel rate; with t_T = 0
    they are added to the work hours instead."""
    shape = (len(machines), len(farm.fields))
    turns, work_hours = np.zeros(shape), np.full(shape, UNABLE_H)
    for i, machine in enumerate(machines):
        for j, f in enumerate(farm.fields):
            cov = coverage.get((machine.id, f.id))
            if cov is not None:
                turns[i, j], work_hours[i, j] = work_of(machine, f.area_m2, cov)
    return turns, work_hours


def work_of(machine: Machine, area_m2: float, cov: FieldCoverage) -> tuple[float, float]:
    """The solver's (turns, work hours) for ``machine`` working ``area_m2`` laid out as
    ``cov``: see :func:`field_work`."""
    work_hours = area_m2 / machine.capacity_m2h
    planned_m = sum(cov.turn_length_m(c) for c in range(CORNERS)) / CORNERS
    if planned_m <= 0.0:
        return float(cov.turns), work_hours
    hours = planned_m / (1000.0 * machine.work_speed_kmh)
    if machine.turn_time_h > 0.0:
        return hours / machine.turn_time_h, work_hours
    return 0.0, work_hours + hours


def field_anchor(field: Field) -> XY:
    """The point a field stands for in the solver's distances: its centroid, or a point
    inside it when the centroid is not (a crescent, a ring)."""
    c = field.boundary.centroid
    if not field.boundary.contains(c):
        c = field.boundary.representative_point()
    return (float(c.x), float(c.y))


def plan_farm(
    farm: Farm,
    machines: Sequence[Machine],
    objective: str | Objective = Objective.MAKESPAN,
    algorithm: str = "ighoa",
    stop: AnyOf | Criterion | None = None,
    seed: int = 1,
    on_generation: GenerationCallback | None = None,
    makespan_slack: float = 0.0,
    finish_within_h: float = 0.0,
) -> FarmPlan:
    """Allocate, order and lay out the work of ``machines`` on ``farm``.

    A time limit in ``stop`` is the limit of the whole: coverage raises
    :class:`~planner.errors.TimeLimitError` (naming the field) once it has passed, and
    the solver stops by then at the latest (see the module's docstring).
    ``on_generation`` is the solver's progress callback, ``makespan_slack`` the
    makespan's slack for road distance and ``finish_within_h`` its deadline
    (:func:`planner.solve.solve`)."""
    obj = Objective.parse(objective)
    if stop is not None and not isinstance(stop, AnyOf):
        stop = AnyOf(stop)
    deadline = Deadline(stop.time_limit_s if stop is not None else None)
    coverage = cover_farm(farm, machines, deadline=deadline)
    network = TransitNetwork(farm)
    problem = farm_problem(farm, machines, coverage, network, obj)
    if stop is not None and deadline.limited:
        seconds = deadline.seconds or 0.0
        left = deadline.left()
        floor = SOLVER_MIN_SHARE * seconds
        if left < floor:
            # With no time left the answer was the unsearched first plan: 8.6 times the
            # makespan of one searched for 5 s more (an outside review). Late, but searched.
            log.warning(
                "coverage and transit took %.1f s of the %g s time limit; the solver has "
                "%.1f s more (a fifth of the limit), the plan %.1f s past it",
                seconds - left,
                seconds,
                floor,
                floor - left,
            )
            deadline = Deadline(floor)
        elif left < 0.5 * seconds:
            log.warning(
                "coverage and transit took %.1f s of the %g s time limit; the solver has %.1f s",
                seconds - left,
                seconds,
                left,
            )
        stop = stop.within(deadline)
    result = solve(
        problem,
        obj,
        algorithm,
        stop,
        seed=seed,
        on_generation=on_generation,
        makespan_slack=makespan_slack,
        finish_within_h=finish_within_h,
    )
    result = fewest_hours_among_equals(settle_unable(result, coverage))
    said = [(machines[i].id, farm.fields[j].id) for i, r in enumerate(result.routes) for j in r]
    say_notes(coverage, said)
    plans = []
    for i, route in enumerate(result.routes):
        machine = machines[i]
        fields = [farm.fields[j] for j in route]
        covs = [coverage[(machine.id, f.id)] for f in fields]
        corners, road = best_corners(farm.garage, covs, network)
        visits, back = lay_out(farm.garage, fields, covs, corners, network)
        plans.append(machine_figures(machine, visits, road, return_path=back))
    return FarmPlan(
        farm=farm,
        machines=tuple(plans),
        objective=obj,
        solver=result,
        coverage=coverage,
        network=network,
    )


def lay_out(
    garage: XY,
    fields: Sequence[Field],
    covs: Sequence[FieldCoverage],
    corners: Sequence[int],
    network: TransitNetwork | None = None,
    start: XY | None = None,
    start_field: str | None = None,
) -> tuple[tuple[Visit, ...], tuple[XY, ...]]:
    """The visits of one route with their approach paths, and the path back to the garage.
    The route starts at ``start`` (default: the garage), inside ``start_field`` if any."""
    visits = []
    where, inside = (garage, None) if start is None else (start, start_field)
    for f, cov, corner in zip(fields, covs, corners, strict=True):
        via = network.route(where, cov.entry(corner), inside, f.id)[1] if network else ()
        visits.append(Visit(f, cov, corner, approach=via))
        where, inside = cov.exit(corner), f.id
    home = network is not None and (fields or start is not None)  # a re-plan's, from the field
    back = network.route(where, garage, inside, None)[1] if network and home else ()
    return tuple(visits), back


def best_corners(
    garage: XY,
    covs: Sequence[FieldCoverage],
    network: TransitNetwork | None = None,
    start: XY | None = None,
    start_field: str | None = None,
) -> tuple[list[int], float]:
    """The start corner of each field along a fixed order that minimises the road driven
    (garage -> fields -> garage along ``network``'s transit, straight lines without it,
    plus in-field driving between cells); exact DP over 4 corners, 16 cached routes a leg.
    The route starts at ``start`` (default: the garage), inside ``start_field`` if any; with
    no field it is the drive from there home."""

    def legs(
        a: Sequence[XY], a_field: str | None, b: Sequence[XY], b_field: str | None
    ) -> FloatArray:
        """Transit lengths from each of ``a`` to each of ``b`` (rows: ``a``)."""
        if network is not None:
            return network.lengths(a, [a_field] * len(a), b, [b_field] * len(b))
        return np.array([[_straight(p, q, a_field, b_field) for q in b] for p in a])

    if not covs:
        return [], 0.0 if start is None else float(legs([start], start_field, [garage], None)[0, 0])
    ids = [cov.field_id for cov in covs]
    n = len(covs)
    cost = np.full((n, CORNERS), np.inf)
    back = np.zeros((n, CORNERS), dtype=np.int64)
    origin, origin_field = (garage, None) if start is None else (start, start_field)
    entries = [[cov.entry(c) for c in range(CORNERS)] for cov in covs]
    exits = [[cov.exit(c) for c in range(CORNERS)] for cov in covs]
    inside = np.array([[cov.transit_inside_m(c) for c in range(CORNERS)] for cov in covs])
    cost[0] = legs([origin], origin_field, entries[0], ids[0])[0] + inside[0]
    for k in range(1, n):
        # total[p, c]: to corner c of field k from corner p of field k - 1
        total = cost[k - 1][:, None] + legs(exits[k - 1], ids[k - 1], entries[k], ids[k])
        back[k] = np.argmin(total, axis=0)
        cost[k] = total[back[k], np.arange(CORNERS)] + inside[k]
    final = cost[n - 1] + legs(exits[n - 1], ids[n - 1], [garage], None)[:, 0]
    corner = int(np.argmin(final))
    corners = [corner]
    for k in range(n - 1, 0, -1):
        corner = int(back[k, corner])
        corners.append(corner)
    return corners[::-1], float(min(final))


def machine_figures(
    machine: Machine,
    visits: tuple[Visit, ...],
    road_m: float,
    return_path: tuple[XY, ...] = (),
    ready_h: float = 0.0,
    ready_work_h: float = 0.0,
    ready_turns: int = 0,
) -> MachinePlan:
    """Formulas (5)-(6) with the coverage's turns: drive ``road_m`` at road speed and rate,
    work S / w at the working rate, and turn at the road fuel rate for the turns' length at
    the working speed when the coverage plans them, else t_T per U-turn. A machine busy
    for ``ready_h`` hours first (a re-plan: the rest of what it is doing) has them added to
    its time, with or without a visit: a machine a re-plan gives nothing new still drives
    those hours and then home, and may be the last to finish. Of them, ``ready_work_h``
    are work and the rest driving and its ``ready_turns`` turns: in its work, turns and
    fuel too (a review: a re-planned tractor's fuel was 26-33 % over plan without them)."""
    field_h = sum(v.field.area_m2 * v.work_share / machine.capacity_m2h for v in visits)
    drive_h = road_m / (1000.0 * machine.road_speed_kmh)
    busy_drive_h = max(ready_h - ready_work_h, 0.0)  # driving, turns included (road rate)
    turn_h = sum(turn_hours(machine, v) for v in visits)
    work_h = field_h + ready_work_h
    return MachinePlan(
        machine=machine,
        visits=visits,
        road_m=road_m,
        work_h=work_h,
        turns=sum(v.coverage.turns for v in visits) + ready_turns,
        time_h=ready_h + drive_h + turn_h + field_h,
        fuel_l=formulas.fuel_l(
            drive_h + busy_drive_h, turn_h, work_h, machine.road_fuel_lh, machine.work_fuel_lh
        ),
        return_path=return_path,
        ready_h=ready_h,
    )


def turn_hours(machine: Machine, visit: Visit) -> float:
    """Hours spent turning in one field: the planned turn paths at the working speed, or
    the paper's t_T per turn when the coverage plans none."""
    metres = visit.coverage.turn_length_m(visit.corner)
    if metres > 0.0:
        return metres / (1000.0 * machine.work_speed_kmh)
    return visit.coverage.turns * machine.turn_time_h


def _straight(a: XY, b: XY, _from: str | None = None, _to: str | None = None) -> float:
    return float(np.hypot(a[0] - b[0], a[1] - b[1]))
