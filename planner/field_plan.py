"""Planning with real field geometry: coverage per machine, allocation, start corners.

1. Every field is covered (:mod:`planner.coverage`) once for each distinct working width
   of the fleet; the U-turns of the machine that works a field replace formula (5)'s
   rectangle estimate, its hours stay S / w.
2. The solver (:func:`planner.solve.solve`) allocates and orders the fields, with the
   distance between two fields taken between their centroids.
3. A post-optimisation picks each field's start corner along every route exactly, by
   dynamic programming over the four corners: the road runs from the exit of one field
   to the entry of the next, and from and back to the garage.
The figures of the result (distance, fuel, time, turns) are those of the driven geometry.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from planner.cost import Objective
from planner.coverage import XY, FieldCoverage, Swath, cover_field
from planner.errors import GeometryError
from planner.farm import Farm, Field
from planner.problem import Machine, Problem, Task
from planner.solve import AnyOf, Result, solve

log = logging.getLogger(__name__)

CORNERS = 4


@dataclass(frozen=True)
class Visit:
    """One field worked by one machine, started at ``corner``."""

    field: Field
    coverage: FieldCoverage
    corner: int
    # Transit from where the machine was (garage or the previous field's exit) to this
    # field's entry: the points in between, along roads or around other fields.
    approach: tuple[XY, ...] = ()

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

    @property
    def field_ids(self) -> list[str]:
        return [v.field.id for v in self.visits]


@dataclass(frozen=True)
class FarmPlan:
    farm: Farm
    machines: tuple[MachinePlan, ...]
    objective: Objective
    solver: Result

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


def cover_farm(farm: Farm, machines: Sequence[Machine]) -> dict[tuple[str, str], FieldCoverage]:
    """Coverage of every field for every machine, keyed (machine id, field id); computed
    once per distinct working width and turning radius."""
    by_width: dict[tuple[float, float], dict[str, FieldCoverage]] = {}
    out: dict[tuple[str, str], FieldCoverage] = {}
    for machine in machines:
        width = machine.working_width_m
        key = (width, machine.min_turn_radius_m)
        if key not in by_width:
            by_width[key] = {}
            for f in farm.fields:
                try:
                    by_width[key][f.id] = cover_field(
                        f.boundary,
                        width,
                        field_id=f.id,
                        angle_deg=f.work_angle_deg,
                        headland_passes=f.headland_passes,
                        turn_radius_m=machine.min_turn_radius_m,
                    )
                except GeometryError as exc:
                    raise GeometryError(
                        f"{farm.source}: machine {machine.id!r} ({width:g} m wide): {exc}"
                    ) from exc
        for f in farm.fields:
            out[(machine.id, f.id)] = by_width[key][f.id]
    return out


def farm_problem(
    farm: Farm, machines: Sequence[Machine], coverage: dict[tuple[str, str], FieldCoverage]
) -> Problem:
    """The solver's view of the farm: centroids, areas, real turn counts per machine."""
    tasks = []
    for f in farm.fields:
        c = f.boundary.centroid
        rect = f.boundary.minimum_rotated_rectangle
        xs, ys = rect.exterior.coords.xy
        sides = sorted(float(np.hypot(xs[k + 1] - xs[k], ys[k + 1] - ys[k])) for k in range(2))
        tasks.append(Task(f.id, float(c.x), float(c.y), f.area_m2, sides[0], sides[1]))
    turns = np.array(
        [[coverage[(mc.id, f.id)].turns for f in farm.fields] for mc in machines], dtype=np.float64
    )
    # The paper has every machine work (its assumption 2: more tasks than machines); with
    # more machines than fields the spare ones simply stay in the garage.
    min_tasks = 1 if len(tasks) >= len(machines) else 0
    return Problem.build(
        machines, tasks, farm.garage, turns=turns, min_tasks_per_machine=min_tasks, name="farm"
    )


def plan_farm(
    farm: Farm,
    machines: Sequence[Machine],
    objective: str | Objective = Objective.MAKESPAN,
    algorithm: str = "ighoa",
    stop: AnyOf | None = None,
    seed: int = 1,
) -> FarmPlan:
    """Allocate, order and lay out the work of ``machines`` on ``farm``."""
    obj = Objective.parse(objective)
    coverage = cover_farm(farm, machines)
    problem = farm_problem(farm, machines, coverage)
    result = solve(problem, obj, algorithm, stop, seed=seed)
    plans = []
    for i, route in enumerate(result.routes):
        machine = machines[i]
        fields = [farm.fields[j] for j in route]
        covs = [coverage[(machine.id, f.id)] for f in fields]
        corners, road = best_corners(farm.garage, covs)
        visits = tuple(Visit(f, c, k) for f, c, k in zip(fields, covs, corners, strict=True))
        plans.append(machine_figures(machine, visits, road))
    return FarmPlan(farm=farm, machines=tuple(plans), objective=obj, solver=result)


def best_corners(garage: XY, covs: Sequence[FieldCoverage]) -> tuple[list[int], float]:
    """The start corner of each field along a fixed order that minimises the road driven
    (garage -> fields -> garage, plus in-field driving between cells); exact DP."""
    if not covs:
        return [], 0.0
    n = len(covs)
    cost = np.full((n, CORNERS), np.inf)
    back = np.zeros((n, CORNERS), dtype=np.int64)
    for c in range(CORNERS):
        cost[0, c] = _dist(garage, covs[0].entry(c)) + covs[0].transit_inside_m(c)
    for k in range(1, n):
        for c in range(CORNERS):
            here = covs[k].entry(c)
            legs = [cost[k - 1, p] + _dist(covs[k - 1].exit(p), here) for p in range(CORNERS)]
            back[k, c] = int(np.argmin(legs))
            cost[k, c] = legs[back[k, c]] + covs[k].transit_inside_m(c)
    final = [cost[n - 1, c] + _dist(covs[n - 1].exit(c), garage) for c in range(CORNERS)]
    corner = int(np.argmin(final))
    corners = [corner]
    for k in range(n - 1, 0, -1):
        corner = int(back[k, corner])
        corners.append(corner)
    return corners[::-1], float(min(final))


def machine_figures(machine: Machine, visits: tuple[Visit, ...], road_m: float) -> MachinePlan:
    """Formulas (5)-(6) with the coverage's turns: drive at road speed and rate, turn
    t_T per U-turn at the road fuel rate, work S / w at the working rate."""
    turns = sum(v.coverage.turns for v in visits)
    work_h = sum(v.field.area_m2 / machine.capacity_m2h for v in visits)
    drive_h = road_m / (1000.0 * machine.road_speed_kmh)
    turn_h = turns * machine.turn_time_h
    return MachinePlan(
        machine=machine,
        visits=visits,
        road_m=road_m,
        work_h=work_h,
        turns=turns,
        time_h=drive_h + turn_h + work_h,
        fuel_l=(drive_h + turn_h) * machine.road_fuel_lh + work_h * machine.work_fuel_lh,
    )


def _dist(a: XY, b: XY) -> float:
    return float(np.hypot(a[0] - b[0], a[1] - b[1]))
