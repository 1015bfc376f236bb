"""Plan the rest of a day's work: machines where they are now, fields done, fields half done.

:func:`replan_farm` takes the farm, the machines still alive with their current position
and ready time (:class:`MachineState`), the fields already done, and for each field in
progress the :class:`Visit` it was planned with and how many of its segments are done
(:class:`FieldProgress`). It returns a :class:`FarmPlan` like :func:`plan_farm`, whose
routes start from each machine's position, so the dispatcher turns it into missions with
the code it already has.

The rest of a field in progress is a task of its remaining segments only (swaths, then
headland ring edges, in the planned visit's driving order, as a mission lays them out):
:func:`remaining_coverage` lays them out again as a coverage whose "corners" are the two
ends of the remaining block (0 and 2: on from where the work stopped; 1 and 3: from the
other end, everything driven backwards), so the corner choice of :func:`best_corners`
enters it from its nearer end. Its area, turns and work hours are scaled to what is left;
each remaining segment is a :class:`Swath` (ring edges too), so the mission of the visit
drives exactly the segments not yet done, each once, and
:attr:`Visit.original_segments` maps them back to the segments of the field's first
planned visit (composed across re-plans: a segment keeps its number).

A field in progress stays with the machine working it, first in its route
(``pinned_machine``), unless ``split_ok``; then it is an ordinary task that starts where
the remaining work begins. Only a machine with the same working width and turning radius
can drive the remaining swaths: when another alive machine differs, the field stays pinned;
when the machine working it is gone and none can take the rest, the field is planned whole
again (the worked part is driven again; logged).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from shapely.geometry import LineString, Point

from planner.choices import Objective
from planner.coverage import XY, FieldCoverage, Swath
from planner.errors import NothingLeftError, ProblemError
from planner.farm import Farm, Field
from planner.field_plan import (
    UNABLE_H,
    FarmPlan,
    MachinePlan,
    Visit,
    best_corners,
    cover_farm,
    field_anchor,
    lay_out,
    machine_figures,
    say_notes,
    settle_unable,
    work_of,
)
from planner.problem import NOT_PINNED, Machine, Problem, Task
from planner.roads import TransitNetwork
from planner.solve import AnyOf, Criterion, solve

log = logging.getLogger(__name__)

Path = tuple[XY, ...]


@dataclass(frozen=True)
class MachineState:
    """An alive machine now: where it is (local metres) and how long until it can start
    (e.g. the rest of the swath it is on)."""

    machine: Machine
    position: XY
    ready_h: float = 0.0
    # Of those hours, the working ones and the turns (the rest of a field it finishes
    # first): counted in its plan's work, turns and fuel as well as its time.
    ready_work_h: float = 0.0
    ready_turns: int = 0


@dataclass(frozen=True)
class FieldProgress:
    """A field being worked: the visit it was planned with, the machine on it, and how
    many of the visit's segments (``Visit.swaths``, then the edges of ``Visit.headland``'s
    rings) are done. Count the segment the machine is on as done when it will finish it
    first (its position at the segment's end, the time left in its ``ready_h``).
    ``split_ok``: the rest may go to another machine when that is better. ``left``, when
    given, names the visit's segments still to do instead (any of them, in any order: work
    done out of the visit's order, or by several machines), and ``segments_done`` is not
    used."""

    visit: Visit
    machine_id: str
    segments_done: int = 0
    split_ok: bool = False
    left: tuple[int, ...] | None = None

    @property
    def field_id(self) -> str:
        return self.visit.field.id

    @property
    def remaining(self) -> list[int]:
        """The visit's segments still to do, in the visit's order."""
        if self.left is not None:
            return sorted(set(self.left))
        return list(range(self.segments_done, len(visit_segments(self.visit))))


def visit_segments(visit: Visit) -> list[tuple[XY, XY]]:
    """A visit's segments in driving order: swaths, then headland ring edges."""
    segments = [(s.start, s.end) for s in visit.swaths]
    for ring in visit.headland:
        segments += list(zip(ring[:-1], ring[1:], strict=True))
    return segments


def remaining_coverage(
    visit: Visit, done: int | Sequence[int]
) -> tuple[FieldCoverage, float, list[list[int]]]:
    """The rest of ``visit`` after ``done`` segments, or its segments ``done`` names as
    left to do (indices in the visit's order), as a coverage (corners 0, 2 forward, 1, 3
    backward), the share of the work left (by working length), and per corner the planned
    visit's index of each remaining segment. Between two remaining segments that are not
    neighbours in the visit the machine moves across the field, implement up."""
    cov, corner = visit.coverage, visit.corner
    swaths = visit.swaths
    segments = visit_segments(visit)
    total = len(segments)
    ahead = list(range(done, total)) if isinstance(done, int) else sorted(set(done))
    if not ahead or ahead[0] < 0 or ahead[-1] >= total:
        told = f"{done} segments done" if isinstance(done, int) else f"segments left {ahead}"
        raise ProblemError(
            f"field {visit.field.id!r}: {told} of {total}; "
            "a finished field belongs with the fields done"
        )
    # One record per segment: the swath (ring edges as swaths of cell -1 - ring), the
    # planned turn onto it and the in-field link onto it from the segment before, and
    # whether that move counts as in-field transit (to another cell, or onto a ring).
    turns, links = cov.turn(corner), cov.link(corner)
    onto_rings, rings_linked = cov.headland_move(corner), cov.headland_link(corner)
    parts: list[Swath] = list(swaths)
    turn_via: list[tuple[XY, ...]] = [()]
    link_via: list[tuple[XY, ...]] = [()]
    transit: list[bool] = [False]
    for k in range(1, len(swaths)):
        turn = turns[k - 1] if k - 1 < len(turns) else ()
        turn_via.append(turn)
        link_via.append(links[k - 1] if k - 1 < len(links) else ())
        transit.append(swaths[k].cell != swaths[k - 1].cell and not turn)
    for r, ring in enumerate(visit.headland):
        for e, (a, b) in enumerate(zip(ring[:-1], ring[1:], strict=True)):
            parts.append(Swath(a, b, -1 - r, e))
            onto = onto_rings[r] if e == 0 and r < len(onto_rings) else ()
            turn_via.append(onto)
            link_via.append(rings_linked[r] if e == 0 and r < len(rings_linked) else ())
            transit.append(e == 0 and not onto)
    work = [s.length_m for s in parts]
    share = sum(work[k] for k in ahead) / max(sum(work), 1e-9)

    def laid(order: list[int]) -> tuple[tuple[Swath, ...], list[Path], list[Path], float]:
        forward = order == sorted(order)
        path = tuple(parts[k] if forward else parts[k].reversed() for k in order)
        turn_moves, link_moves, inside = [], [], 0.0
        for a, b in itertools.pairwise(order):
            later = max(a, b)  # the move between two segments is kept with the later one
            planned = abs(a - b) == 1  # neighbours: the visit's own move between them
            turn = turn_via[later] if forward else tuple(reversed(turn_via[later]))
            link = link_via[later] if forward else tuple(reversed(link_via[later]))
            if not planned:
                turn, link = (), ()
            turn_moves.append(turn)
            link_moves.append(link)
            if transit[later] or not planned:
                begin = path[len(turn_moves) - 1].end
                end = path[len(turn_moves)].start
                inside += LineString([begin, *link, end]).length
        return path, turn_moves, link_moves, inside

    orders = [ahead, ahead[::-1], ahead, ahead[::-1]]
    laid_out = [laid(o) for o in orders]
    rest = [parts[k] for k in ahead]
    swath_moves = [(a, b) for a, b in itertools.pairwise(ahead) if parts[b].cell >= 0]
    coverage = dataclasses.replace(
        cov,
        swaths=laid_out[0][0],
        headland=(),
        turns=len(swath_moves),
        cell_transitions=sum(1 for a, b in swath_moves if parts[a].cell != parts[b].cell),
        swath_length_m=sum(s.length_m for s in rest if s.cell >= 0),
        headland_length_m=sum(s.length_m for s in rest if s.cell < 0),
        area_m2=cov.area_m2 * share,
        paths=tuple(p for p, _, _, _ in laid_out),
        headland_paths=((),) * 4,
        transits_m=tuple(t for _, _, _, t in laid_out),
        # Without planned turns a coverage has none at all (the mission keeps the
        # implement down from the first segment to the last).
        turn_paths=tuple(tuple(t) for _, t, _, _ in laid_out) if cov.turn_paths else (),
        links=tuple(tuple(k) for _, _, k, _ in laid_out),
        headland_moves=((),) * 4,
        headland_links=((),) * 4,
    )
    log.debug("field %s: %d of %d segments left", visit.field.id, len(rest), total)
    return coverage, share, orders


def replan_farm(
    farm: Farm,
    machines: Sequence[MachineState],
    done: Iterable[str] = (),
    in_progress: Sequence[FieldProgress] = (),
    objective: str | Objective = Objective.MAKESPAN,
    algorithm: str = "ighoa",
    stop: AnyOf | Criterion | None = None,
    seed: int = 1,
    previous: FarmPlan | None = None,
    makespan_slack: float = 0.0,
    finish_within_h: float = 0.0,
) -> FarmPlan:
    """Allocate, order and lay out the rest of the work on ``farm`` for the alive
    ``machines``, from where they are now. Fields in ``done`` are left out; fields in
    ``in_progress`` are planned for their remaining segments; the others whole, as
    :func:`plan_farm` does. With ``previous`` (the plan being carried out), its remaining
    routes are the solver's warm start. Each machine's route ends at the garage.
    ``makespan_slack``: as :func:`plan_farm`'s; ``finish_within_h``: :func:`plan_farm`'s
    deadline, in hours from now (the machines' ready times count in the makespan)."""
    if not machines:
        raise ProblemError("no machines: the fleet is empty")
    done_ids = set(done)
    for fid in done_ids:
        farm.field(fid)  # raises for an unknown field
    by_machine = {s.machine.id: i for i, s in enumerate(machines)}
    progress: dict[str, FieldProgress] = {}
    for entry in in_progress:
        farm.field(entry.field_id)
        if entry.field_id in done_ids or entry.field_id in progress:
            raise ProblemError(f"field {entry.field_id!r} is given as done or in progress twice")
        if not entry.remaining:
            done_ids.add(entry.field_id)
            continue
        progress[entry.field_id] = entry
    todo = [f for f in farm.fields if f.id not in done_ids]
    if not todo:
        raise NothingLeftError(
            "no tasks: every field is done, or what is left of it lies in the part of its "
            "mission a vehicle keeps"
        )
    fleet = [s.machine for s in machines]
    same_farm = previous is not None and previous.farm is farm
    known = previous.coverage if previous is not None and same_farm else None
    network = previous.network if previous is not None and same_farm else None
    network = network or TransitNetwork(farm)
    coverage = cover_farm(
        dataclasses.replace(farm, fields=tuple(todo)), fleet, known, every_field=False
    )
    for f in [f for f in todo if all((mc.id, f.id) in coverage.unable for mc in fleet)]:
        log.warning(
            "field %s: no machine left can work it (%s); it stays undone",
            f.id,
            coverage.unable[(fleet[0].id, f.id)],
        )
        todo.remove(f)
    if not todo:
        raise ProblemError("no tasks: no machine left can work the fields that are not done")

    m, n = len(fleet), len(todo)
    covs: list[list[FieldCoverage | None]] = [
        [coverage.get((mc.id, f.id)) for f in todo] for mc in fleet
    ]
    shares = np.ones(n)
    anchors: list[XY] = [field_anchor(f) for f in todo]
    orders: dict[int, list[list[int]]] = {}
    rest_of: dict[int, FieldCoverage] = {}
    pins = np.full(n, NOT_PINNED, dtype=np.int64)
    for j, f in enumerate(todo):
        p = progress.get(f.id)
        if p is None:
            continue
        cov = p.visit.coverage
        fits = [
            mc.working_width_m == cov.working_width_m and mc.min_turn_radius_m == cov.turn_radius_m
            for mc in fleet
        ]
        worker = by_machine.get(p.machine_id)
        if worker is None and not any(fits):
            log.warning(
                "field %s: machine %s is gone and no other can drive its remaining swaths; "
                "the field is planned whole again",
                f.id,
                p.machine_id,
            )
            continue
        rest, shares[j], orders[j] = remaining_coverage(p.visit, p.remaining)
        rest_of[j] = rest
        anchors[j] = rest.entry(0)
        for i in range(m):
            if fits[i]:
                covs[i][j] = rest
        if worker is not None and (not p.split_ok or not all(fits)):
            pins[j] = worker
        elif worker is None:
            log.info("field %s: machine %s is gone; its rest goes to another", f.id, p.machine_id)

    # Solver distances: transit between anchors, from each machine's position, to the garage.
    ids: list[str | None] = [None, *(f.id for f in todo)]
    lengths = network.length_matrix([farm.garage, *anchors], ids)
    inside = [_field_at(farm, s.position) for s in machines]
    start = network.lengths([s.position for s in machines], inside, anchors, ids[1:])
    turns, work_hours = np.zeros((m, n)), np.full((m, n), UNABLE_H)
    for i, mc in enumerate(fleet):
        for j, f in enumerate(todo):
            laid = covs[i][j]
            if laid is None:
                continue  # it cannot work that field (UNABLE_H)
            share = shares[j] if laid is rest_of.get(j) else 1.0
            turns[i, j], work_hours[i, j] = work_of(mc, f.area_m2 * share, laid)
    tasks = [
        Task(f.id, anchors[j][0], anchors[j][1], f.area_m2 * shares[j]) for j, f in enumerate(todo)
    ]
    problem = Problem(
        machines=tuple(fleet),
        tasks=tuple(tasks),
        dist=np.array(lengths[1:, 1:]),
        start_dist=start,
        end_dist=np.tile(lengths[1:, 0], (m, 1)),
        turns=turns,
        work_hours=work_hours,
        min_tasks_per_machine=0,
        name="replan",
        depot=farm.garage,
        ready_h=np.array([s.ready_h for s in machines], dtype=np.float64),
        pinned_machine=pins,
    )
    warm = _warm_routes(previous, fleet, todo) if previous is not None else None
    result = solve(
        problem,
        objective,
        algorithm,
        stop,
        seed=seed,
        initial_routes=warm,
        makespan_slack=makespan_slack,
        finish_within_h=finish_within_h,
    )

    result = settle_unable(result, coverage)
    # What a coverage leaves to be said, for the fields a machine is newly given (their own
    # were said by the plan before; a rest keeps the coverage of the visit it is part of).
    before = previous.machines if previous is not None else ()
    had = {(p.machine.id, v.field.id) for p in before for v in p.visits}
    given = [(fleet[i].id, todo[j].id) for i, r in enumerate(result.routes) for j in r]
    say_notes(coverage, [pair for pair in given if pair not in had and pair in coverage])
    plans: list[MachinePlan] = []
    for i, route in enumerate(result.routes):
        state = machines[i]
        fields: list[Field] = [todo[j] for j in route]
        route_covs = [_able(covs[i][j]) for j in route]
        corners, road = best_corners(
            farm.garage, route_covs, network, start=state.position, start_field=inside[i]
        )
        visits, back = lay_out(
            farm.garage,
            fields,
            route_covs,
            corners,
            network,
            start=state.position,
            start_field=inside[i],
        )
        visits = tuple(
            dataclasses.replace(
                v,
                work_share=float(shares[j]),
                original_segments=_composed(progress[todo[j].id].visit, orders[j][v.corner]),
            )
            if route_covs[k] is rest_of.get(j)
            else v
            for k, (j, v) in enumerate(zip(route, visits, strict=True))
        )
        plans.append(
            machine_figures(
                state.machine,
                visits,
                road,
                return_path=back,
                ready_h=state.ready_h,
                ready_work_h=state.ready_work_h,
                ready_turns=state.ready_turns,
            )
        )
    return FarmPlan(
        farm=farm,
        machines=tuple(plans),
        objective=result.objective,
        solver=result,
        coverage=known.merged(coverage) if known is not None else coverage,
        network=network,
    )


def _able(cov: FieldCoverage | None) -> FieldCoverage:
    """A planned visit's coverage (settle_unable has made sure there is one)."""
    assert cov is not None
    return cov


def _composed(visit: Visit, order: Sequence[int]) -> tuple[int, ...]:
    """Segment numbers of the field's first layout for a rest visit laid out in ``order``
    (indices among ``visit``'s segments): through ``visit``'s own map when it is itself
    the rest of an earlier visit."""
    first = visit.original_segments
    return tuple(first[k] for k in order) if first else tuple(order)


def _field_at(farm: Farm, point: XY) -> str | None:
    """The field a point lies in, if any (a machine at work, or just done)."""
    p = Point(point)
    for f in farm.fields:
        if f.boundary.covers(p):
            return f.id
    return None


def _warm_routes(
    previous: FarmPlan, fleet: Sequence[Machine], todo: Sequence[Field]
) -> list[list[int]]:
    """The previous plan's routes of the alive machines, fields done or gone left out."""
    index = {f.id: j for j, f in enumerate(todo)}
    old = {mp.machine.id: mp.field_ids for mp in previous.machines}
    return [[index[fid] for fid in old.get(mc.id, []) if fid in index] for mc in fleet]
