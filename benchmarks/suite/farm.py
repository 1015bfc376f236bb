"""A seeded farm of ``fields`` fields and ``machines`` machines, and a makespan lower bound.

The farm is a square whose side grows with the square root of the number of fields (the
fields' density stays the same: ``land_km2`` of land a field, by default
:data:`FIELD_DENSITY_KM2`, where the fields cover 3.5 % of the land), the garage at its
centre. Fields are rectangles of log-normal area (median 12 ha, 2-60 ha), 1:1 to 1:3.
Machines differ in working width (3-12 m), working speed (6-12 km/h, field efficiency
0.75), road speed (15-40 km/h) and time per U-turn (0.5-1.5 min), so a field's service
time depends on the machine: the area over its capacity plus its turns (the paper's
rectangle model, formula 6), as the planner costs it. Same seed, same farm.

Two lower bounds on the makespan, both the value of the linear relaxation of assigning
fields to machines (unrelated machines, R||Cmax) with a cost c_ij for field j on machine i,
and at least the longest field's cheapest cost on its own:

- :func:`makespan_lower_bound` ignores travel: c_ij = p_ij, machine i's service time.
- :func:`travel_lower_bound` counts the travel no plan avoids: c_ij = p_ij + e_ij / v_i, v_i
  the machine's road speed and e_ij half the two shortest legs that can lead into and out of
  field j on machine i (:func:`planner.relaxation.incident_legs_m`; these c_ij are
  :func:`planner.relaxation.unavoidable_hours`, whose duals weigh the squeeze's hours). Why
  it holds: machine i's route start_i -> j_1 -> ... -> j_r -> end_i has r + 1 legs and each
  field has two of them, one in and one out, to two different nodes (other fields, or the
  start and the end, which count as two nodes even where they are the same place: a
  one-field route is start -> j -> end). So the legs at field j add up to at least the two
  shortest of {D(j, k) : k another field} + {D(start_i, j), D(j, end_i)} taken as a
  multiset, and as every leg ends at most two fields, the route is at least half the sum of
  that over its fields. The time of a machine is then at least sum_j c_ij over its fields
  (its share of the start's and end's legs, left out, is >= 0), and the longest field's term
  becomes min_i p_ij + (D(start_i, j) + D(j, end_i)) / v_i: its machine drives there and
  back. It leaves out what a route needs beyond that: the garage at the centre of the farm
  is ~17 km from a field on average, and a route that reaches out to radius R drives at
  least 2R (not additive over fields, so not in this relaxation).

Any weights lambda on the machines (summing to one) give a bound sum_j min_i lambda_i c_ij
(the makespan is at least every lambda-weighted mean of the machines' loads, and each
field adds at least its lambda-cheapest cost to it). The weights are the optimal duals of
the relaxation (:mod:`planner.relaxation`, which the squeeze weighs the machines' hours
with); the bound is evaluated from them in numpy, so it is valid whatever the LP solver's
tolerance (before 2026-11-25 the weights came from 400 multiplicative steps, which stopped
0.8 % short of the LP at 500 x 30: 52.14 h, now 52.54 h; until 2026-11-26 OR-Tools' GLOP
solved it, to the same bounds).

How far the travel-free bound is from the best assignment that ignores travel, from above:
:func:`travel_free_assignment` (an R||Cmax local search) gives a makespan with no travel
that an optimum with no travel is at or below; so the travel-free optimum lies between
the two, and a plan's gap to LB beyond that is its driving and what driving costs it.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from planner.cost import CostTables
from planner.problem import Machine, Problem, Task, swaths_across
from planner.relaxation import machine_weights, unavoidable_hours, weighted_bound

FIELD_DENSITY_KM2 = 4.0  # square kilometres of farm per field
FIELD_EFFICIENCY = 0.75  # share of the working speed x width that is real work


def generate_farm(
    fields: int,
    machines: int,
    seed: int = 1,
    land_km2: float = FIELD_DENSITY_KM2,
    passes: int = 1,
) -> Problem:
    """The farm ``fields`` x ``machines`` of ``seed``, ``land_km2`` square kilometres of land
    a field (how spread out it is), each field worked ``passes`` times in one visit (its
    hours and turns that many times over: a season's work, where travel weighs less);
    objective: makespan (hours). The machines, the fields' sizes and where they are do
    not depend on ``land_km2`` and ``passes`` but for the land's scale."""
    if fields < 1 or machines < 1:
        raise ValueError(f"a farm needs fields and machines, not {fields} x {machines}")
    if not land_km2 > 0.0:
        raise ValueError(f"a farm needs land: land_km2 must be positive, not {land_km2}")
    if isinstance(passes, bool) or not isinstance(passes, int) or passes < 1:
        raise ValueError(f"a field is worked at least once: passes must be >= 1, not {passes!r}")
    rng = np.random.default_rng(seed)
    side_m = 1000.0 * math.sqrt(land_km2 * fields)
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
    # The U-turns between swaths, as coverage lays out a rectangle (the farm objective's
    # fields are ours, not the paper's, whose n_turn counts one more: rectangle_turns).
    turns = np.array(
        [[max(swaths_across(t.width_m, mc.working_width_m) - 1, 0) for t in tasks] for mc in fleet],
        dtype=np.float64,
    )
    once = Problem.build(
        fleet,
        tasks,
        (side_m / 2.0, side_m / 2.0),
        turns=turns,
        min_tasks_per_machine=0,
        name=f"farm{fields}x{machines}s{seed}",
    )
    if passes == 1:
        return once
    return dataclasses.replace(
        once,
        turns=once.turns * passes,
        work_hours=once.work_hours * passes,
        name=f"{once.name}p{passes}",
    )


def service_hours(problem: Problem) -> np.ndarray:
    """Hours machine i spends in field j, [machine, field]: work plus turns."""
    return CostTables.of(problem).task_hours


def makespan_lower_bound(problem: Problem) -> float:
    """A lower bound on the makespan in hours that ignores all travel (see the module)."""
    p = service_hours(problem)
    return max(float(p.min(axis=0).max()), assignment_bound(p))


def travel_lower_bound(problem: Problem) -> float:
    """A lower bound on the makespan in hours that counts the travel no plan avoids (see
    the module); at least :func:`makespan_lower_bound`'s relaxation with every cost
    raised, so never below it."""
    tables = CostTables.of(problem)
    ends = (tables.start_dist + tables.end_dist) * tables.road_hours_per_m[:, None]
    alone = tables.task_hours + ends
    return max(float(alone.min(axis=0).max()), assignment_bound(unavoidable_hours(tables)))


def assignment_bound(costs: np.ndarray) -> float:
    """sum_j min_i lambda_i costs[i, j] for the weights lambda of the LP relaxation's
    optimal duals (``costs``: [machine, field]); a lower bound on the makespan of any
    assignment of the fields with these costs (see the module)."""
    weights = machine_weights(costs)
    assert weights is not None  # no time limit
    return weighted_bound(costs, weights)


def travel_free_assignment(problem: Problem, kicks: int = 300, seed: int = 1) -> np.ndarray:
    """A machine for every field that makes the makespan short when travel is ignored
    ([field] machine index; its makespan: :func:`assignment_makespan`), an upper bound on
    the travel-free optimum beside :func:`makespan_lower_bound`'s lower one. The fields
    start on their machine of least weighted hours (the relaxation's duals); then, until
    no move shortens the longest machine without another reaching it, the best move of
    one of its fields to any machine, or swap of one with any other field; from the best
    found, ``kicks`` times, three random fields go to random machines and the descent runs
    again. Same seed, same answer. O(n) numpy work a move, O(r n) a swap (r: the longest
    machine's fields)."""
    hours = service_hours(problem)
    m, n = hours.shape
    weights = machine_weights(hours)
    assert weights is not None  # no time limit
    machine = np.argmin(weights[:, None] * hours, axis=0)
    best = _descend(hours, machine)
    rng = np.random.default_rng(seed)
    for _ in range(kicks):
        machine = best.copy()
        machine[rng.integers(n, size=3)] = rng.integers(m, size=3)
        machine = _descend(hours, machine)
        if assignment_makespan(hours, machine) < assignment_makespan(hours, best):
            best = machine
    return best


def assignment_makespan(hours: np.ndarray, machine: np.ndarray) -> float:
    """The longest machine's hours when field j is done by ``machine[j]``, travel ignored."""
    return float(_loads(hours, machine).max())


def _loads(hours: np.ndarray, machine: np.ndarray) -> np.ndarray:
    return np.bincount(
        machine, weights=hours[machine, np.arange(hours.shape[1])], minlength=hours.shape[0]
    )


def _descend(hours: np.ndarray, machine: np.ndarray) -> np.ndarray:
    """Steepest descent on the longest machine: the best move or swap of one of its fields
    that leaves both machines it touches shorter than it was, until there is none."""
    machine = machine.copy()
    load = _loads(hours, machine)
    while True:
        top = int(np.argmax(load))
        own = np.flatnonzero(machine == top)
        if own.size == 0:
            return machine
        # Move field own[a] to machine k: [a, k] the longer of the two after it.
        moved = np.maximum(load[None, :] + hours[:, own].T, (load[top] - hours[top, own])[:, None])
        moved[:, top] = np.inf
        a, k = np.unravel_index(int(np.argmin(moved)), moved.shape)
        value, change = moved[a, k], (own[a], int(k), -1)
        # Swap field own[a] with field other[b] of machine theirs[b].
        other = np.flatnonzero(machine != top)
        if other.size:
            theirs = machine[other]
            mine_after = load[top] - hours[top, own][:, None] + hours[top, other][None, :]
            theirs_after = (
                load[theirs][None, :] - hours[theirs, other][None, :] + hours[np.ix_(theirs, own)].T
            )
            swapped = np.maximum(mine_after, theirs_after)
            a2, b = np.unravel_index(int(np.argmin(swapped)), swapped.shape)
            if swapped[a2, b] < value:
                value, change = swapped[a2, b], (own[a2], int(theirs[b]), int(other[b]))
        if not value < load[top] - 1e-9:
            return machine
        field, to, back = change
        machine[field] = to
        if back >= 0:
            machine[back] = top
        load = _loads(hours, machine)
