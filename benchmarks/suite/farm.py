"""A seeded farm of ``fields`` fields and ``machines`` machines, and a makespan lower bound.

The farm is a square whose side grows with the square root of the number of fields (the
fields' density stays the same), the garage at its centre. Fields are rectangles of
log-normal area (median 12 ha, 2-60 ha), 1:1 to 1:3. Machines differ in working width
(3-12 m), working speed (6-12 km/h, field efficiency 0.75), road speed (15-40 km/h) and
time per U-turn (0.5-1.5 min), so a field's service time depends on the machine: the
area over its capacity plus its turns (the paper's rectangle model, formula 6), as the
planner costs it. Same seed, same farm.

:func:`makespan_lower_bound` ignores travel: the makespan is at least the longest
field's shortest service time, and at least the value of the linear relaxation of
assigning fields to machines (unrelated machines, R||Cmax). Any weights lambda on the
machines (summing to one) give a bound sum_j min_i lambda_i p_ij (LP duality); the weights
are improved by a few hundred multiplicative steps and the best bound is kept.
"""

from __future__ import annotations

import math

import numpy as np

from planner.problem import Machine, Problem, Task

FIELD_DENSITY_KM2 = 4.0  # square kilometres of farm per field
FIELD_EFFICIENCY = 0.75  # share of the working speed x width that is real work


def generate_farm(fields: int, machines: int, seed: int = 1) -> Problem:
    """The farm ``fields`` x ``machines`` of ``seed``; objective: makespan (hours)."""
    if fields < 1 or machines < 1:
        raise ValueError(f"a farm needs fields and machines, not {fields} x {machines}")
    rng = np.random.default_rng(seed)
    side_m = 1000.0 * math.sqrt(FIELD_DENSITY_KM2 * fields)
    fleet = []
    for i in range(machines):
        width = float(rng.uniform(3.0, 12.0))
        work_kmh = float(rng.uniform(6.0, 12.0))
        fleet.append(
            Machine(
                id=f"M{i + 1:02d}",
                working_width_m=round(width, 2),
                capacity_m2h=round(width * work_kmh * 1000.0 * FIELD_EFFICIENCY, 1),
                road_speed_kmh=round(float(rng.uniform(15.0, 40.0)), 1),
                turn_time_h=round(float(rng.uniform(0.5, 1.5)) / 60.0, 5),
                road_fuel_lh=10.0,
                work_fuel_lh=20.0,
                work_speed_kmh=round(work_kmh, 1),
            )
        )
    tasks = []
    for j in range(fields):
        area = float(np.clip(rng.lognormal(math.log(12e4), 0.6), 2e4, 60e4))
        aspect = float(rng.uniform(1.0, 3.0))
        width = math.sqrt(area / aspect)
        tasks.append(
            Task(
                id=f"F{j + 1:03d}",
                x=round(float(rng.uniform(0.0, side_m)), 1),
                y=round(float(rng.uniform(0.0, side_m)), 1),
                area_m2=round(area, 1),
                width_m=round(width, 1),
                length_m=round(area / width, 1),
            )
        )
    return Problem.build(
        fleet,
        tasks,
        (side_m / 2.0, side_m / 2.0),
        min_tasks_per_machine=0,
        name=f"farm{fields}x{machines}s{seed}",
    )


def service_hours(problem: Problem) -> np.ndarray:
    """Hours machine i spends in field j, [machine, field]: work plus turns."""
    turn_h = problem.machine_array("turn_time_h")
    return problem.work_hours + problem.turns * turn_h[:, None]


def makespan_lower_bound(problem: Problem, steps: int = 400) -> float:
    """A lower bound on the makespan in hours that ignores all travel (see the module)."""
    p = service_hours(problem)
    longest = float(p.min(axis=0).max())
    speed = 1.0 / p.mean(axis=1)  # start: weights as the machines' work rates
    lam = speed / speed.sum()
    best = 0.0
    for step in range(steps):
        scaled = lam[:, None] * p
        owner = scaled.argmin(axis=0)
        best = max(best, float(scaled[owner, np.arange(p.shape[1])].sum()))
        # The machine that takes the most (its load over the bound) gets a larger weight.
        load = np.bincount(owner, weights=p[owner, np.arange(p.shape[1])], minlength=len(lam))
        lam = lam * np.exp(0.5 / math.sqrt(step + 1) * (load / max(load.mean(), 1e-12) - 1.0))
        lam /= lam.sum()
    return max(longest, best)
